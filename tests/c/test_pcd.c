/* pb_pcd: a PCD header checked before PCL reads it. Files PCL writes pass; what is not a
 * PCD, or promises more than it holds, is refused with the file and the line or byte. */
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include "pb_check.h"
#include "pb_pcd.h"

static char dir[64];

#define HEAD(fields, size, type, count, n, data) \
    "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS " fields "\nSIZE " size "\nTYPE " type \
    "\nCOUNT " count "\nWIDTH " n "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " n "\nDATA " data "\n"

/* Writes a header and bytes of data to DIR/NAME; returns its path. */
static const char *write_pcd(const char *name, const char *header, size_t data_bytes)
{
    const char *path = pb_check_write_file(dir, name, header);
    FILE *f = fopen(path, "ab");
    for (size_t i = 0; i < data_bytes; i++) fputc(i & 0xff, f);
    fclose(f);
    return path;
}

static void test_good_files(void)
{
    pb_err_t err;
    pb_pcd_header_t h;
    const char *p = write_pcd("bin.pcd", HEAD("x y z intensity", "4 4 4 4", "F F F F", "1 1 1 1", "3", "binary"), 48);
    if (CHECK_OK(pb_pcd_check(p, &h, &err), err.msg)) return;
    CHECK(h.points == 3 && h.fields == 4 && h.record_bytes == 16 && strcmp(h.data, "binary") == 0);
    p = write_pcd("ascii.pcd", HEAD("x y z", "4 4 4", "F F F", "1 1 1", "2", "ascii"), 0);
    FILE *f = fopen(p, "a");
    fputs("1 2 3\n4 5 6\n", f);
    fclose(f);
    CHECK_OK(pb_pcd_check(p, &h, &err), err.msg);
    /* COUNT may be left out; a field of 8 floats and one of 2-byte unsigned */
    p = write_pcd("nocount.pcd",
                  "VERSION .7\nFIELDS x y z ring t\nSIZE 4 4 4 2 8\nTYPE F F F U F\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n"
                  "DATA binary\n", 2 * 22);
    CHECK_OK(pb_pcd_check(p, &h, &err), err.msg);
    CHECK(h.record_bytes == 22);
    /* binary_compressed: the two sizes, the packed bytes within the file */
    p = write_pcd("lzf.pcd", HEAD("x y z", "4 4 4", "F F F", "1 1 1", "2", "binary_compressed"), 0);
    f = fopen(p, "ab");
    const unsigned char sizes[8] = {10, 0, 0, 0, 24, 0, 0, 0};
    fwrite(sizes, 1, 8, f);
    fwrite("0123456789", 1, 10, f);
    fclose(f);
    CHECK_OK(pb_pcd_check(p, &h, &err), err.msg);
}

static void test_bad_files(void)
{
    struct { const char *name, *header; size_t bytes; const char *says; } cases[] = {
        {"floats.pcd", "\x01\x9a\x10\x41\xd0\x72\x1f\x41", 4000, "floats.pcd:1: "},
        {"text.pcd", "hello\nworld\n", 0, ":1: 'hello' is not a PCD header keyword"},
        {"short.pcd", HEAD("x y z", "4 4 4", "F F F", "1 1 1", "100", "binary"), 50,
         ": byte 168: 100 points of 12 bytes need 1200 bytes of data, the file holds 50"},
        {"wh.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 10\nHEIGHT 2\nPOINTS 21\nDATA ascii\n", 0,
         ":7: WIDTH x HEIGHT (10 x 2) is not POINTS (21)"},
        {"size.pcd", "FIELDS x y z\nSIZE 4 3 4\n", 0, ":2: SIZE '3': 1, 2, 4 or 8 expected"},
        {"type.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F Q F\n", 0, ":3: TYPE 'Q': I, U or F expected"},
        {"f2.pcd", "FIELDS x\nSIZE 2\nTYPE F\nWIDTH 1\nPOINTS 1\nDATA ascii\n", 0, "field 1: a float of 2 bytes"},
        {"count.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 0 1\n", 0, ":4: COUNT '0': 1 to 4096 expected"},
        {"n.pcd", "FIELDS x y z\nSIZE 4 4\n", 0, ":2: SIZE has 2 values for 3 fields"},
        {"order.pcd", "FIELDS x y z\nSIZE 4 4 4\nFIELDS x\n", 0, ":3: FIELDS out of order or twice"},
        {"form.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA lzma\n", 0,
         ":6: DATA: ascii, binary or binary_compressed expected"},
        {"lack.pcd", "FIELDS x y z\nSIZE 4 4 4\nWIDTH 1\nPOINTS 1\nDATA ascii\n", 0, ":5: the header lacks TYPE"},
        {"points.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nPOINTS -1\n", 0, ":5: POINTS: one whole number"},
        {"lzf.pcd", HEAD("x y z", "4 4 4", "F F F", "1 1 1", "2", "binary_compressed"), 0,
         "binary_compressed data without its two sizes"},
        /* PCL reads on after DATA over blank and comment lines, and takes a keyword line as
         * header: binary data that begins so would crash it (found by fuzz_import_scans) */
        {"keyword.pcd", HEAD("x y z", "4 4 4", "F F F", "1 1 1", "2", "binary") "\n# c\nCOLUMNS a b\n", 30,
         ": byte 169: the data begins like a header line ('COLUMNS a')"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        pb_err_t err = {""};
        const char *p = write_pcd(cases[i].name, cases[i].header, cases[i].bytes);
        CHECK_CASE(cases[i].name, pb_pcd_check(p, NULL, &err) == -1);
        CHECK_CASE(cases[i].name, strstr(err.msg, cases[i].name) != NULL);
        CHECK_CASE(cases[i].name, strstr(err.msg, cases[i].says) != NULL);
        if (!strstr(err.msg, cases[i].says)) fprintf(stderr, "  said: %s\n", err.msg);
    }
    /* a line without end, longer than a header line can be */
    char *big = malloc(20000);
    memset(big, 'A', 19999);
    big[19999] = 0;
    pb_err_t err = {""};
    CHECK(pb_pcd_check(write_pcd("long.pcd", big, 0), NULL, &err) == -1);
    CHECK_CONTAINS(err.msg, "long.pcd:1: a header line longer than");
    free(big);
    CHECK(pb_pcd_check("/nonexistent/map.pcd", NULL, &err) == -1);
    CHECK_CONTAINS(err.msg, "/nonexistent/map.pcd: No such file");
}

int main(void)
{
    snprintf(dir, sizeof dir, "/tmp/test_pcd_%d", (int)getpid());
    if (mkdir(dir, 0700) != 0) { perror(dir); return 1; }
    test_good_files();
    test_bad_files();
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0) fprintf(stderr, "could not remove %s\n", dir);
    return pb_check_report("test_pcd");
}
