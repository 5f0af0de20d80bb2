/* map_source: the paged prior map from a site folder (see map_source.h). */
#include "map_source.h"
#include "pb_pcd.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>
#include <cerrno>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <algorithm>
#include <cmath>
#include <future>
#include <map>
#include <memory>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

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

/* The map's points a part at a time, in the file's order (finite points only, as PCL's
 * PointXYZ gives them): binary PCD with float x, y, z (what the mapper and the map
 * builders write) is streamed; other forms (ascii, binary_compressed) are read whole by PCL. */
typedef int (*points_fn)(void *user, const float *xyz, size_t n, pb_err_t *err);

static int pcl_points(const char *pcd, points_fn fn, void *user, pb_err_t *err)
{
    std::vector<float> xyz;
    if (pb_pcd_read_xyz(pcd, &xyz, nullptr, err) != 0) return -1;
    return fn(user, xyz.data(), xyz.size() / 3, err);
}

static int read_points(const char *pcd, points_fn fn, void *user, pb_err_t *err)
{
    FILE *f = std::fopen(pcd, "rb");
    if (!f) return pb_err_set(err, "%s: %s", pcd, strerror(errno));
    /* the header: the fields' sizes, types and counts, the points, the data form */
    std::vector<std::string> fields, sizes, types, counts;
    std::string data;
    uint64_t points = 0;
    char line[4096];
    while (data.empty() && std::fgets(line, sizeof line, f)) {
        std::vector<std::string> w;
        char *save = nullptr;
        for (char *t = strtok_r(line, " \t\r\n", &save); t; t = strtok_r(nullptr, " \t\r\n", &save)) w.push_back(t);
        if (w.empty() || w[0][0] == '#') continue;
        std::vector<std::string> rest(w.begin() + 1, w.end());
        if (w[0] == "FIELDS") fields = rest;
        else if (w[0] == "SIZE") sizes = rest;
        else if (w[0] == "TYPE") types = rest;
        else if (w[0] == "COUNT") counts = rest;
        else if (w[0] == "POINTS" && rest.size() == 1) points = std::strtoull(rest[0].c_str(), nullptr, 10);
        else if (w[0] == "DATA" && rest.size() == 1) data = rest[0];
    }
    long data_at = std::ftell(f);
    /* what PCL's reader would crash or stumble on is refused here */
    if (pb_pcd_check(pcd, nullptr, err) != 0) {
        std::fclose(f);
        return -1;
    }
    const char *bad = points == 0 ? "no POINTS"
                      : std::find(fields.begin(), fields.end(), "x") == fields.end() ||
                                std::find(fields.begin(), fields.end(), "y") == fields.end() ||
                                std::find(fields.begin(), fields.end(), "z") == fields.end()
                            ? "PCD has no x, y, z fields"
                            : nullptr;
    if (bad) {
        std::fclose(f);
        return pb_err_set(err, "%s: %s", pcd, bad);
    }
    if (counts.empty()) counts.assign(fields.size(), "1");
    int at[3] = {-1, -1, -1};
    size_t record = 0;
    bool plain = data == "binary" && sizes.size() == fields.size() && types.size() == fields.size() &&
                 counts.size() == fields.size() && data_at > 0;
    for (size_t i = 0; plain && i < fields.size(); i++) {
        int size = std::atoi(sizes[i].c_str()), count = std::atoi(counts[i].c_str());
        for (int a = 0; a < 3; a++)
            if (fields[i] == std::string(1, (char)('x' + a))) {
                plain &= size == 4 && types[i] == "F" && count == 1;
                at[a] = (int)record;
            }
        plain &= size > 0 && size <= 8 && count > 0 && count <= 4096;   /* else PCL judges the header */
        if (plain) record += (size_t)size * (size_t)count;
    }
    if (!plain || at[0] < 0 || at[1] < 0 || at[2] < 0) {
        std::fclose(f);
        return pcl_points(pcd, fn, user, err);
    }
    /* binary records, a part at a time */
    std::vector<uint8_t> buf(record * 65536);
    std::vector<float> xyz;
    for (uint64_t done = 0; done < points;) {
        size_t want = (size_t)std::min<uint64_t>(points - done, 65536);
        if (std::fread(buf.data(), record, want, f) != want) {
            std::fclose(f);
            return pb_err_set(err, "%s: byte %" PRIu64 ": corrupt PCD: the file ends before its %" PRIu64 " points",
                              pcd, (uint64_t)data_at + done * record, points);
        }
        xyz.clear();
        for (size_t i = 0; i < want; i++) {
            float p[3];
            for (int a = 0; a < 3; a++) std::memcpy(&p[a], buf.data() + i * record + at[a], 4);
            if (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])) xyz.insert(xyz.end(), p, p + 3);
        }
        done += want;
        if (fn(user, xyz.data(), xyz.size() / 3, err) != 0) { std::fclose(f); return -1; }
    }
    std::fclose(f);
    return 0;
}

namespace {

/* A scratch file (unlinked at once) in dir, or in the temporary directory when dir is empty. */
FILE *scratch(const std::string &dir)
{
    if (dir.empty()) return tmpfile();
    std::string path = dir + "/.map-tiles.XXXXXX";
    int fd = mkstemp(&path[0]);
    if (fd < 0) return nullptr;
    unlink(path.c_str());
    FILE *f = fdopen(fd, "w+b");
    if (!f) close(fd);
    return f;
}

/* The tiled preparation's state (core/map_tiles.h, "the tiled preparation"): the points
 * held per tile in a scratch file, a bounded part in memory at a time. */
struct Tiling {
    pb_regmap_config_t cfg;
    double tile_m = 0;
    pb_regmap_info_t info;
    FILE *spill = nullptr, *body = nullptr, *cells = nullptr;
    uint64_t spilled = 0;
    std::map<std::pair<int32_t, int32_t>, std::vector<float>> held;     /* per tile: points not yet spilled */
    std::map<std::pair<int32_t, int32_t>, std::vector<std::pair<uint64_t, uint32_t>>> parts;   /* spilled */
    size_t held_floats = 0;
    static const size_t kHeldFloats = 4 << 20;   /* 16 MB of points in memory at most */

    ~Tiling()
    {
        for (FILE *f : {spill, body, cells}) if (f) std::fclose(f);
    }

    int flush(pb_err_t *err)
    {
        for (auto &h : held) {
            if (h.second.empty()) continue;
            if (std::fwrite(h.second.data(), sizeof(float), h.second.size(), spill) != h.second.size())
                return pb_err_set(err, "scratch file of the tiles: cannot write (disk full?)");
            parts[h.first].push_back({spilled, (uint32_t)(h.second.size() / 3)});
            spilled += h.second.size() * sizeof(float);
            h.second.clear();
            h.second.shrink_to_fit();
        }
        held_floats = 0;
        return 0;
    }

    /* 1. every point to its tile and the tiles whose margin it lies in */
    static int take(void *user, const float *xyz, size_t n, pb_err_t *err)
    {
        Tiling *t = (Tiling *)user;
        for (size_t i = 0; i < n; i++) {
            const float *p = xyz + 3 * i;
            t->info.points++;
            for (int a = 0; a < 3; a++) {
                t->info.min[a] = std::min(t->info.min[a], (double)p[a]);
                t->info.max[a] = std::max(t->info.max[a], (double)p[a]);
            }
            int32_t to[9][2];
            int k = pb_tiles_point_tiles(&t->cfg, t->tile_m, p, to);
            for (int j = 0; j < k; j++) {
                std::vector<float> &v = t->held[{to[j][0], to[j][1]}];
                v.insert(v.end(), p, p + 3);
            }
            t->held_floats += 3 * (size_t)k;
            if (t->held_floats >= kHeldFloats && t->flush(err) != 0) return -1;
        }
        return 0;
    }
};

int read_back(FILE *f, uint64_t at, void *buf, size_t bytes)
{
    return fseeko(f, (off_t)at, SEEK_SET) == 0 && std::fread(buf, 1, bytes, f) == bytes ? 0 : -1;
}

int copy_file(FILE *from, FILE *to)
{
    std::vector<uint8_t> buf(1 << 20);
    if (fseeko(from, 0, SEEK_SET) != 0) return -1;
    for (size_t n; (n = std::fread(buf.data(), 1, buf.size(), from)) > 0;)
        if (std::fwrite(buf.data(), 1, n, to) != n) return -1;
    return std::ferror(from) ? -1 : 0;
}

}  // namespace

/* map.pcd prepared tile by tile into out (written from its start): memory follows a tile
 * and the held points, not the map. Scratch files go into scratch_dir. */
static int write_tiled(const char *pcd, FILE *out, const std::string &scratch_dir, double tile_m,
                       pb_regmap_info_t *info, size_t *places, size_t *bytes, pb_err_t *err)
{
    pb_tiles_source_t id;
    if (map_source_file_id(pcd, &id, err) != 0) return -1;
    Tiling t;
    pb_regmap_config_default(&t.cfg);
    t.tile_m = tile_m;
    t.info = pb_regmap_info_t();
    for (int a = 0; a < 3; a++) { t.info.min[a] = HUGE_VAL; t.info.max[a] = -HUGE_VAL; }
    t.spill = scratch(scratch_dir);
    t.body = scratch(scratch_dir);
    t.cells = scratch(scratch_dir);
    if (!t.spill || !t.body || !t.cells)
        return pb_err_set(err, "%s: no scratch file in %s: %s", pcd, scratch_dir.empty() ? "the temporary directory" :
                          scratch_dir.c_str(), strerror(errno));
    /* 1. the points, streamed, to the tiles that need them */
    if (read_points(pcd, Tiling::take, &t, err) != 0 || t.flush(err) != 0) return -1;
    if (t.info.points == 0) return pb_err_set(err, "%s: no finite points", pcd);
    t.held.clear();
    /* 2. each tile prepared from its points and margin, in (tx, ty) order; its fine and
     *    rough cells kept aside for the place descriptors */
    std::vector<pb_tiles_row_t> rows;
    std::vector<uint64_t> cells_at;   /* per row: where its cells for the places start */
    pb_loc::places_config_t pc;
    pb_loc::places_builder_t *pb = pb_loc::places_builder_new(pc);
    std::unique_ptr<pb_loc::places_builder_t, void (*)(pb_loc::places_builder_t *)> pb_own(pb, pb_loc::places_builder_destroy);
    /* two tiles at a time, the second on another thread (a tile's preparation reads only
     * its own points), each written in turn: the same file as one at a time */
    struct Prepared {
        std::vector<float> xyz, cell_xyz;
        std::vector<uint8_t> tile, cell_ground;
        pb_tiles_row_t row;
        pb_err_t err;
        int rc = 0;
    } pair[2];
    std::vector<float> cell_xyz;
    std::vector<uint8_t> cell_ground;
    uint64_t cells_bytes = 0;
    for (auto part = t.parts.begin(); part != t.parts.end();) {
        int k = 0;
        std::future<void> second;
        for (; k < 2 && part != t.parts.end(); k++, ++part) {
            Prepared &P = pair[k];
            P.xyz.clear();
            for (const auto &c : part->second) {
                size_t at = P.xyz.size();
                P.xyz.resize(at + 3 * (size_t)c.second);
                if (read_back(t.spill, c.first, P.xyz.data() + at, 12 * (size_t)c.second) != 0) {
                    if (second.valid()) second.get();
                    return pb_err_set(err, "%s: scratch file of the tiles: cannot read back byte %" PRIu64, pcd, c.first);
                }
            }
            const int32_t tx = part->first.first, ty = part->first.second;
            auto prepare = [&t, &P, tile_m, tx, ty] {
                P.tile.clear(); P.cell_xyz.clear(); P.cell_ground.clear();
                P.rc = pb_tiles_prepare_tile(&t.cfg, tile_m, tx, ty, P.xyz.data(), P.xyz.size() / 3, &P.row, &P.tile,
                                             &P.cell_xyz, &P.cell_ground, &P.err);
            };
            if (k == 0) second = std::async(std::launch::async, prepare);
            else prepare();
        }
        second.get();
        for (int i = 0; i < k; i++) {
            Prepared &P = pair[i];
            if (P.rc != 0) return pb_err_set(err, "%s: %s", pcd, P.err.msg);
            if (P.tile.empty()) continue;
            uint32_t n = (uint32_t)P.cell_ground.size();
            if (std::fwrite(P.tile.data(), 1, P.tile.size(), t.body) != P.tile.size() ||
                std::fwrite(&n, 4, 1, t.cells) != 1 || std::fwrite(P.cell_xyz.data(), 12, n, t.cells) != n ||
                std::fwrite(P.cell_ground.data(), 1, n, t.cells) != n)
                return pb_err_set(err, "%s: scratch file of the tiles: cannot write (disk full?)", pcd);
            cells_at.push_back(cells_bytes);
            cells_bytes += 4 + 13 * (uint64_t)n;
            pb_loc::places_builder_extent(pb, P.cell_xyz.data(), n);
            rows.push_back(P.row);
            t.info.cells += P.row.fine;
            t.info.coarse_cells += P.row.coarse;
        }
    }
    t.parts.clear();
    std::fclose(t.spill);
    t.spill = nullptr;
    if (t.info.cells == 0)
        return pb_err_set(err, "%s: no voxel of %g m holds %d points with a plane or line", pcd, t.cfg.voxel_m,
                          t.cfg.min_points);
    /* 3. the place descriptors from the cells kept aside: the ground, then the structure */
    for (int pass = 0; pass < 2; pass++)
        for (uint64_t at : cells_at) {
            uint32_t n;
            if (read_back(t.cells, at, &n, 4) != 0) return pb_err_set(err, "%s: scratch file: cannot read back", pcd);
            cell_xyz.resize(3 * (size_t)n);
            cell_ground.resize(n);
            if (read_back(t.cells, at + 4, cell_xyz.data(), 12 * (size_t)n) != 0 ||
                read_back(t.cells, at + 4 + 12 * (uint64_t)n, cell_ground.data(), n) != 0)
                return pb_err_set(err, "%s: scratch file: cannot read back", pcd);
            if (pass == 0) pb_loc::places_builder_ground(pb, cell_xyz.data(), cell_ground.data(), n);
            else pb_loc::places_builder_structure(pb, cell_xyz.data(), cell_ground.data(), n);
        }
    pb_loc::places_t *p = pb_loc::places_builder_finish(pb_own.release());
    std::vector<uint8_t> pbytes;
    if (p) pb_loc::places_encode(p, &pbytes);
    if (places) *places = pb_loc::places_count(p);
    pb_loc::places_destroy(p);
    /* 4. the file: header and table, the tiles, the places */
    std::vector<uint8_t> head;
    if (pb_tiles_encode_head(&t.cfg, tile_m, t.info, rows, id, pbytes.size(), &head, err) != 0) return -1;
    if (std::fwrite(head.data(), 1, head.size(), out) != head.size() || copy_file(t.body, out) != 0 ||
        std::fwrite(pbytes.data(), 1, pbytes.size(), out) != pbytes.size() || std::fflush(out) != 0)
        return pb_err_set(err, "%s: cannot write the tile file (disk full?)", pcd);
    if (info) *info = t.info;
    if (bytes) *bytes = (size_t)ftello(out);
    return 0;
}

/* No map.tiles: the map prepared now into an unlinked temporary file. */
static int prepare_temporary(const std::string &pcd, pb_err_t *err)
{
    fprintf(stderr, "localizer: %s has no map.tiles next to it: preparing it now (build it once with "
            "map-tiles --map %s --out DIR/map.tiles to start faster)\n", pcd.c_str(), pcd.c_str());
    FILE *f = tmpfile();
    if (!f) return pb_err_set(err, "temporary tile file for %s: %s", pcd.c_str(), strerror(errno));
    if (write_tiled(pcd.c_str(), f, "", MAP_SOURCE_TILE_M, nullptr, nullptr, nullptr, err) != 0) {
        fclose(f);
        return -1;
    }
    int fd = dup(fileno(f));
    fclose(f);
    if (fd < 0) return pb_err_set(err, "temporary tile file for %s: %s", pcd.c_str(), strerror(errno));
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
    std::string tmp = std::string(out_path) + ".tmp", dir = out_path;
    size_t slash = dir.rfind('/');
    dir = slash == std::string::npos ? "." : dir.substr(0, std::max<size_t>(slash, 1));
    FILE *f = std::fopen(tmp.c_str(), "wb");
    if (!f) return pb_err_set(err, "%s: cannot write: %s", tmp.c_str(), strerror(errno));
    int rc = write_tiled(pcd, f, dir, tile_m, info, places, bytes, err);
    if (std::fclose(f) != 0 && rc == 0) rc = pb_err_set(err, "%s: cannot write", tmp.c_str());
    if (rc == 0 && std::rename(tmp.c_str(), out_path) != 0) rc = pb_err_set(err, "%s: cannot write", out_path);
    if (rc != 0) std::remove(tmp.c_str());
    return rc;
}
