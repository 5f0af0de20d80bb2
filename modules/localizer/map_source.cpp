/* map_source: the paged prior map from a site folder (see map_source.h). */
#include "map_source.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>
#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>

struct map_source {
    std::string path;
    int fd = -1;
    pb_tiles_t *tiles = nullptr;
};

static int read_at(void *user, uint64_t offset, void *buf, size_t len)
{
    int fd = *(int *)user;
    uint8_t *p = (uint8_t *)buf;
    while (len > 0) {
        ssize_t r = pread(fd, p, len, (off_t)offset);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) return -1;
        p += r; len -= (size_t)r; offset += (uint64_t)r;
    }
    return 0;
}

int map_source_file_id(const char *path, pb_tiles_source_t *id, pb_err_t *err)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) return pb_err_set(err, "%s: %s", path, strerror(errno));
    std::vector<uint8_t> buf(1 << 20);
    uLong crc = crc32(0L, Z_NULL, 0);
    uint64_t bytes = 0;
    for (;;) {
        ssize_t r = read(fd, buf.data(), buf.size());
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) { int e = errno; close(fd); return pb_err_set(err, "%s: byte %" PRIu64 ": %s", path, bytes, strerror(e)); }
        if (r == 0) break;
        crc = crc32(crc, buf.data(), (uInt)r);
        bytes += (uint64_t)r;
    }
    close(fd);
    id->bytes = bytes;
    id->crc32 = (uint32_t)crc;
    return 0;
}

int map_source_prepare(const char *pcd, double tile_m, std::vector<uint8_t> *out, pb_regmap_info_t *info,
                       size_t *places, pb_err_t *err)
{
    pb_tiles_source_t id;
    if (map_source_file_id(pcd, &id, err) != 0) return -1;
    pb_regmap_t *map = pb_regmap_load(pcd, nullptr, nullptr, err);
    if (!map) return -1;
    /* the place descriptors of the whole map, for a start with no prior */
    pb_loc::places_config_t pc;
    pb_loc::places_t *p = pb_loc::places_build(map, pc);
    std::vector<uint8_t> pbytes;
    if (p) pb_loc::places_encode(p, &pbytes);
    if (places) *places = pb_loc::places_count(p);
    pb_loc::places_destroy(p);
    int rc = pb_tiles_encode(map, tile_m, id, pbytes, out, err);
    if (info) pb_regmap_info(map, info);
    pb_regmap_destroy(map);
    if (rc != 0) {
        char msg[sizeof err->msg];
        snprintf(msg, sizeof msg, "%s", err->msg);
        return pb_err_set(err, "%s: %s", pcd, msg);
    }
    return 0;
}

/* No map.tiles: the map prepared now into an unlinked temporary file. */
static int prepare_temporary(const std::string &pcd, pb_err_t *err)
{
    fprintf(stderr, "localizer: %s has no map.tiles next to it: preparing the whole map now (build it once with "
            "map-tiles --map %s --out DIR/map.tiles to start faster and with less memory)\n", pcd.c_str(), pcd.c_str());
    std::vector<uint8_t> bytes;
    if (map_source_prepare(pcd.c_str(), MAP_SOURCE_TILE_M, &bytes, nullptr, nullptr, err) != 0) return -1;
    FILE *f = tmpfile();
    if (!f) return pb_err_set(err, "temporary tile file for %s: %s", pcd.c_str(), strerror(errno));
    int fd = dup(fileno(f));
    bool ok = fd >= 0 && fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size() && fflush(f) == 0;
    fclose(f);
    if (!ok) {
        if (fd >= 0) close(fd);
        return pb_err_set(err, "temporary tile file for %s: cannot write %zu bytes", pcd.c_str(), bytes.size());
    }
    return fd;
}

map_source_t *map_source_open(const std::string &site, const pb_tiles_config_t *cfg, pb_err_t *err)
{
    map_source_t *s = new map_source_t();
    std::string pcd = site + "/map.pcd", tiles = site + "/map.tiles";
    struct stat st;
    bool have_pcd = stat(pcd.c_str(), &st) == 0;
    if (stat(tiles.c_str(), &st) != 0) {
        if (!have_pcd) {
            pb_err_set(err, "%s: %s, and no %s either", pcd.c_str(), strerror(errno), tiles.c_str());
            delete s;
            return nullptr;
        }
        s->path = pcd + " (prepared into a temporary tile file)";
        s->fd = prepare_temporary(pcd, err);
    } else {
        s->path = tiles;
        s->fd = open(tiles.c_str(), O_RDONLY | O_CLOEXEC);
        if (s->fd < 0) pb_err_set(err, "%s: %s", tiles.c_str(), strerror(errno));
    }
    if (s->fd < 0) { delete s; return nullptr; }
    off_t size = lseek(s->fd, 0, SEEK_END);
    s->tiles = size < 0 ? nullptr : pb_tiles_open(read_at, &s->fd, (uint64_t)size, s->path.c_str(), cfg, err);
    if (!s->tiles) { close(s->fd); delete s; return nullptr; }
    /* tiles of another map than the site's map.pcd: never used */
    pb_tiles_source_t want = {0, 0}, have = pb_tiles_source(s->tiles);
    if (have_pcd && map_source_file_id(pcd.c_str(), &want, err) != 0) {
        map_source_close(s);
        return nullptr;
    }
    if (have_pcd && (want.bytes != have.bytes || want.crc32 != have.crc32)) {
        pb_err_set(err, "%s was prepared from another map than %s (%" PRIu64 " bytes, CRC-32 %08x; the map has %"
                       PRIu64 " bytes, CRC-32 %08x): rebuild it with map-tiles --map %s --out %s (make does it for "
                       "the bundled sites)", tiles.c_str(), pcd.c_str(), have.bytes, have.crc32, want.bytes, want.crc32,
                       pcd.c_str(), tiles.c_str());
        map_source_close(s);
        return nullptr;
    }
    return s;
}

void map_source_close(map_source_t *s)
{
    if (!s) return;
    pb_tiles_destroy(s->tiles);
    if (s->fd >= 0) close(s->fd);
    delete s;
}

const pb_regmap_t *map_source_map(const map_source_t *s) { return pb_tiles_map(s->tiles); }
const char *map_source_path(const map_source_t *s) { return s->path.c_str(); }

pb_loc::places_t *map_source_places(const map_source_t *s, pb_err_t *err)
{
    err->msg[0] = '\0';
    std::vector<uint8_t> bytes;
    if (pb_tiles_read_places(s->tiles, &bytes, err) != 0 || bytes.empty()) return nullptr;
    char msg[200];
    pb_loc::places_t *p = pb_loc::places_decode(bytes.data(), bytes.size(), msg, sizeof msg);
    if (!p) pb_err_set(err, "%s: place descriptors: %s", s->path.c_str(), msg);
    return p;
}

int map_source_page(map_source_t *s, double x, double y, pb_err_t *err) { return pb_tiles_page(s->tiles, x, y, err); }

void map_source_stats(const map_source_t *s, pb_tiles_stats_t *st) { pb_tiles_stats(s->tiles, st); }

int map_source_write_tiles(const char *pcd, const char *out_path, double tile_m, pb_regmap_info_t *info,
                           size_t *places, size_t *bytes, pb_err_t *err)
{
    std::vector<uint8_t> data;
    if (map_source_prepare(pcd, tile_m, &data, info, places, err) != 0) return -1;
    std::string tmp = std::string(out_path) + ".tmp";
    FILE *f = std::fopen(tmp.c_str(), "wb");
    if (!f || std::fwrite(data.data(), 1, data.size(), f) != data.size() || std::fclose(f) != 0 ||
        std::rename(tmp.c_str(), out_path) != 0) {
        std::remove(tmp.c_str());
        return pb_err_set(err, "%s: cannot write", tmp.c_str()), -1;
    }
    if (bytes) *bytes = data.size();
    return 0;
}
