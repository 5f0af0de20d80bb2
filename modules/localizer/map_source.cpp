/* map_source: whole or paged prior map from a site folder (see map_source.h). */
#include "map_source.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <cerrno>
#include <cstring>

struct map_source {
    std::string path;
    int fd = -1;
    pb_tiles_t *tiles = nullptr;
    pb_regmap_t *whole = nullptr;
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

map_source_t *map_source_open(const std::string &site, bool paged, const pb_tiles_config_t *cfg, pb_err_t *err)
{
    map_source_t *s = new map_source_t();
    std::string pcd = site + "/map.pcd", tiles = site + "/map.tiles";
    struct stat st_t, st_p;
    if (!paged) {
        s->path = pcd;
        s->whole = pb_regmap_load(pcd.c_str(), nullptr, nullptr, err);
        if (!s->whole) { delete s; return nullptr; }
        return s;
    }
    s->path = tiles;
    if (stat(tiles.c_str(), &st_t) != 0) {
        pb_err_set(err, "%s: %s (build it with map-tiles --map %s --out %s)", tiles.c_str(), strerror(errno), pcd.c_str(),
                   tiles.c_str());
        delete s;
        return nullptr;
    }
    if (stat(pcd.c_str(), &st_p) == 0 &&
        (st_p.st_mtim.tv_sec > st_t.st_mtim.tv_sec ||
         (st_p.st_mtim.tv_sec == st_t.st_mtim.tv_sec && st_p.st_mtim.tv_nsec > st_t.st_mtim.tv_nsec))) {
        pb_err_set(err, "%s is older than %s: rebuild it (map-tiles --map %s --out %s) or delete it", tiles.c_str(),
                   pcd.c_str(), pcd.c_str(), tiles.c_str());
        delete s;
        return nullptr;
    }
    s->fd = open(tiles.c_str(), O_RDONLY | O_CLOEXEC);
    if (s->fd < 0) { pb_err_set(err, "%s: %s", tiles.c_str(), strerror(errno)); delete s; return nullptr; }
    s->tiles = pb_tiles_open(read_at, &s->fd, (uint64_t)st_t.st_size, tiles.c_str(), cfg, err);
    if (!s->tiles) { close(s->fd); delete s; return nullptr; }
    return s;
}

void map_source_close(map_source_t *s)
{
    if (!s) return;
    pb_tiles_destroy(s->tiles);
    pb_regmap_destroy(s->whole);
    if (s->fd >= 0) close(s->fd);
    delete s;
}

const pb_regmap_t *map_source_map(const map_source_t *s) { return s->tiles ? pb_tiles_map(s->tiles) : s->whole; }
int map_source_paged(const map_source_t *s) { return s->tiles ? 1 : 0; }
const char *map_source_path(const map_source_t *s) { return s->path.c_str(); }

int map_source_page(map_source_t *s, double x, double y, pb_err_t *err)
{
    return s->tiles ? pb_tiles_page(s->tiles, x, y, err) : 0;
}

void map_source_stats(const map_source_t *s, pb_tiles_stats_t *st)
{
    if (s->tiles) { pb_tiles_stats(s->tiles, st); return; }
    pb_regmap_info_t info;
    pb_regmap_info(s->whole, &info);
    *st = pb_tiles_stats_t();
    st->fine_cells = info.cells;
    st->coarse_cells = info.coarse_cells;
}
