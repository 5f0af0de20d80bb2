/* Unit tests of common/pb_ground: save/load round trip (mm quantum), unknown cells,
 * bilinear lookup, the car's z/roll/pitch, and refused files; a large grid held and
 * written in blocks (only those with known ground), its round trip and its damaged
 * files refused. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "pb_check.h"
#include "pb_ground.h"

static off_t size_of(const char *p)
{
    struct stat st;
    return stat(p, &st) ? -1 : st.st_size;
}

/* Rewrites n bytes of file p at offset off. */
static void poke(const char *p, long off, const void *b, size_t n)
{
    FILE *f = fopen(p, "r+b");
    if (!f) return;
    fseek(f, off, SEEK_SET);
    fwrite(b, 1, n, f);
    fclose(f);
}

static void copy_file(const char *from, const char *to)
{
    char buf[65536];
    FILE *a = fopen(from, "rb"), *b = fopen(to, "wb");
    size_t n;
    while (a && b && (n = fread(buf, 1, sizeof buf, a)) > 0) fwrite(buf, 1, n, b);
    if (a) fclose(a);
    if (b) fclose(b);
}

/* A grid of 10,000 x 6,000 corners (2.5 x 1.5 km: more than PB_GROUND_DENSE_MAX) with
 * known ground in three places: held in blocks, written as blocks. */
static void blocked(const char *dir)
{
    char path[256], data[256], keep[256];
    snprintf(path, sizeof path, "%s/b.yaml", dir);
    snprintf(data, sizeof data, "%s/b.blocks", dir);
    snprintf(keep, sizeof keep, "%s/b.keep", dir);
    const int nx = 10000, ny = 6000;
    pb_ground_t *g = pb_ground_create(100.0, -50.0, 0.25, nx, ny);
    CHECK(g != NULL && pb_ground_blocks(g, NULL) == 0);
    if (!g) return;
    /* a road across a block corner, a patch at the grid's far corner (a partial block), one corner alone */
    for (int j = 100; j < 160; j++)
        for (int i = 30; i < 300; i++) pb_ground_set(g, i, j, 12.0 + 0.01 * i - 0.003 * j);
    for (int j = ny - 20; j < ny; j++)
        for (int i = nx - 30; i < nx; i++) pb_ground_set(g, i, j, 40.0 + 0.002 * i);
    pb_ground_set(g, 5000, 3000, 7.25);
    pb_ground_set(g, 5001, 3000, NAN);          /* unknown: holds no block */
    const size_t held = pb_ground_blocks(g, NULL);
    CHECK(held == 5 * 2 + 2 + 1);               /* road: x blocks 0-4, y 1-2; the far corner: two, partial; the lone corner */
    double z;
    CHECK(pb_ground_height(g, 100 + 0.25 * 63.5, -50 + 0.25 * 127.5, &z) == 0 &&    /* a cell on 4 blocks */
          fabs(z - (12.0 + 0.01 * 63.5 - 0.003 * 127.5)) < 1e-5);
    pb_err_t err = { "" };
    CHECK(pb_ground_save(g, path, &err) == 0);
    CHECK(size_of(data) == 8 + (off_t)held * (8 + 2 * 64 * 64 + 8));
    pb_ground_t *h = pb_ground_load(path, &err);
    CHECK(h != NULL);
    if (!h) { fprintf(stderr, "%s\n", err.msg); pb_ground_destroy(g); return; }
    size_t differ = 0;
    for (int j = 0; j < ny; j += (j > 200 && j < ny - 30 ? 97 : 1))
        for (int i = 0; i < nx; i++) {
            double a = pb_ground_get(g, i, j), b = pb_ground_get(h, i, j);
            differ += isnan(a) ? !isnan(b) : !(fabs(a - b) <= 0.0005 + 1e-6);
        }
    CHECK(differ == 0 && pb_ground_get(h, 5000, 3000) == pb_ground_get(h, 5000, 3000) &&
          fabs(pb_ground_get(h, 5000, 3000) - 7.25) < 0.0006);
    CHECK(pb_ground_blocks(h, NULL) == held);
    pb_ground_destroy(h);
    /* refused, with the file and the byte: a changed height (checksum), a block out of
     * order, a short file, a wrong count in the YAML */
    copy_file(data, keep);
    poke(data, 8 + 8 + 2 * 700, "\x12", 1);
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "b.blocks: byte 8:") && strstr(err.msg, "checksum"));
    copy_file(keep, data);
    const long rec = 8 + 2 * 64 * 64 + 8;
    char first[8];
    FILE *f = fopen(keep, "rb");
    if (f) { CHECK(fread(first, 1, 8, f) == 8 && fseek(f, 8, SEEK_SET) == 0 && fread(first, 1, 8, f) == 8); fclose(f); }
    poke(data, 8 + rec, first, 8);              /* the second block says it is the first: refused (its checksum too) */
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "b.blocks: byte 8216:"));
    copy_file(keep, data);
    f = fopen(data, "r+b");
    if (f) { CHECK(ftruncate(fileno(f), 8 + rec * 3 + 100) == 0); fclose(f); }
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "b.blocks: byte 8:") && strstr(err.msg, "expected"));
    copy_file(keep, data);
    h = pb_ground_load(path, &err);             /* the copy back loads */
    CHECK(h != NULL);
    pb_ground_destroy(h);
    f = fopen(path, "r+b");
    char text[1024] = "";
    size_t tn = f ? fread(text, 1, sizeof text - 1, f) : 0;
    if (f) fclose(f);
    char *bl = strstr(text, "blocks: ");
    CHECK(tn > 0 && bl != NULL);
    if (bl) {
        bl[8] = '9';                             /* blocks: 92 (12 written) */
        f = fopen(path, "wb");
        if (f) { fwrite(text, 1, strlen(text), f); fclose(f); }
        h = pb_ground_load(path, &err);
        CHECK(h == NULL && strstr(err.msg, "b.blocks: byte 8:"));
    }
    pb_ground_destroy(g);
    /* a small grid mostly unknown (1 of 100 blocks): blocks too; a quarter known: the PGM */
    g = pb_ground_create(0, 0, 0.25, 640, 640);
    for (int j = 0; j < 64; j++)
        for (int i = 0; i < 64; i++) pb_ground_set(g, 320 + i, 192 + j, 1.0);
    CHECK(pb_ground_save(g, path, &err) == 0 && size_of(data) == 8 + rec);
    unlink(data);
    for (int k = 0; k < 25; k++) pb_ground_set(g, 64 * (k % 10), 64 * (k / 10), 2.0);
    char pgm[256];
    snprintf(pgm, sizeof pgm, "%s/b.pgm", dir);
    CHECK(pb_ground_save(g, path, &err) == 0 && size_of(data) == -1 && size_of(pgm) > 640 * 640 * 2);
    h = pb_ground_load(path, &err);
    CHECK(h != NULL && pb_ground_get(h, 330, 210) == 1.0 && pb_ground_get(h, 64, 128) == 2.0);
    pb_ground_destroy(h);
    pb_ground_destroy(g);
    /* a grid the size of a continent holds nothing until set */
    g = pb_ground_create(0, 0, 0.25, 1 << 28, 1 << 28);
    CHECK(g != NULL);
    if (g) {
        pb_ground_set(g, (1 << 28) - 1, 12345678, 3.0);
        CHECK(pb_ground_blocks(g, NULL) == 1 && pb_ground_get(g, (1 << 28) - 1, 12345678) == 3.0);
        pb_ground_destroy(g);
    }
    unlink(path); unlink(data); unlink(keep); unlink(pgm);
}

int main(void)
{
    char dir[] = "/tmp/test_ground_XXXXXX";
    if (!mkdtemp(dir)) return 1;
    char path[256], pgm[256];
    snprintf(path, sizeof path, "%s/g.yaml", dir);
    snprintf(pgm, sizeof pgm, "%s/g.pgm", dir);
    /* a plane rising 5 % along x and falling 2 % along y, a hole at (3, 3) */
    pb_ground_t *g = pb_ground_create(-1, -2, 0.5, 21, 11);
    for (int j = 0; j < 11; j++)
        for (int i = 0; i < 21; i++) pb_ground_set(g, i, j, 100 + 0.05 * (-1 + i * 0.5) - 0.02 * (-2 + j * 0.5));
    pb_ground_set(g, 8, 10, NAN);
    pb_err_t err = { "" };
    CHECK(pb_ground_save(g, path, &err) == 0);
    pb_ground_t *h = pb_ground_load(path, &err);
    CHECK(h != NULL);
    if (!h) { fprintf(stderr, "%s\n", err.msg); return 1; }
    double z;
    CHECK(pb_ground_height(h, 2.3, 0.7, &z) == 0 && fabs(z - (100 + 0.05 * 2.3 - 0.02 * 0.7)) < 0.001);
    CHECK(isnan(pb_ground_get(h, 8, 10)));
    CHECK(pb_ground_height(h, 50, 0, &z) == -1);        /* outside */
    double roll, pitch;
    CHECK(pb_ground_car(h, 0, 0, 0, 2.7, 1.5, &z, &roll, &pitch) == 0);
    CHECK(fabs(pitch + atan(0.05)) < 1e-3);             /* uphill: nose up, pitch < 0 */
    CHECK(fabs(roll - atan(-0.02)) < 1e-3);             /* left side (+y) lower */
    CHECK(fabs(z - 100) < 0.002);
    pb_ground_destroy(h);
    /* refused: a truncated PGM, a wrong header, a bad YAML key */
    FILE *f = fopen(pgm, "r+b");
    CHECK(f != NULL);
    if (f) { CHECK(ftruncate(fileno(f), 100) == 0); fclose(f); }
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "g.pgm") && strstr(err.msg, "byte"));
    f = fopen(pgm, "wb");
    fputs("P2\n21 11\n65535\n", f);
    fclose(f);
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "P5"));
    f = fopen(path, "a");
    fputs("colour: red\n", f);
    fclose(f);
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "g.yaml:") && strstr(err.msg, "colour"));
    pb_ground_destroy(g);
    unlink(path); unlink(pgm);
    blocked(dir);
    rmdir(dir);
    return pb_check_report("test_ground");
}
