// build-ground: a site's prior map (PCD) -> its ground model (ground.yaml + ground.pgm, or
// ground.blocks for a large grid).
//
// The shell: options, the PCD through PCL, the core (ground_build.h), the files
// (common/pb_ground.h). Works on any prior map, simulated or assembled from real scans.
#include <cstdio>
#include <vector>

#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include "ground_build.h"
#include "pb_err.h"
#include "pb_ground.h"
#include "pb_opt.h"
#include "pb_pcd.h"

static void usage(FILE *f)
{
    std::fprintf(f,
        "usage: build-ground --map MAP.pcd --out GROUND.yaml [--cell 0.25] [--window 1.0] [--step 0.18]\n"
        "                    [--grade 0.12] [--fill 2.5] [--quiet]\n"
        "\n"
        "Derives the ground model of a site (a height grid of the drivable and walkable\n"
        "surface, docs/sites.md) from its prior map: per cell the lowest map point, kept\n"
        "when it is at most STEP + GRADE x WINDOW above the lowest point within WINDOW\n"
        "metres (kerbs and slopes pass, car roofs and walls do not), a 3x3 median, and\n"
        "holes up to FILL metres from ground filled from their neighbours. Writes\n"
        "GROUND.yaml and GROUND.pgm (16-bit heights, 0 = unknown), or GROUND.blocks (the\n"
        "same heights in 64 x 64 blocks, only where ground is known) for a grid of more\n"
        "than 2^24 corners (docs/sites.md).\n");
}

int main(int argc, char **argv)
{
    const char *map_path = nullptr, *out_path = nullptr;
    gb_config_t cfg;
    gb_config_default(&cfg);
    int quiet = 0;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("map", &map_path), PB_OPT_REQUIRED("out", &out_path), PB_OPT_DOUBLE("cell", &cfg.cell_m, 0.02, 10),
        PB_OPT_DOUBLE("window", &cfg.window_m, 0.1, 20), PB_OPT_DOUBLE("step", &cfg.step_m, 0, 5),
        PB_OPT_DOUBLE("grade", &cfg.grade, 0, 2), PB_OPT_DOUBLE("fill", &cfg.fill_m, 0, 50), PB_OPT_FLAG("quiet", &quiet, 1),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse("build-ground", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    pcl::PointCloud<pcl::PointXYZ> cloud;
    pb_err_t perr;
    if (pb_pcd_check(map_path, nullptr, &perr) != 0) {   /* PCL's reader trusts the header */
        std::fprintf(stderr, "build-ground: %s\n", perr.msg);
        return 1;
    }
    try {
        if (pcl::io::loadPCDFile(map_path, cloud) < 0) {
            std::fprintf(stderr, "build-ground: %s: cannot read as PCD\n", map_path);
            return 1;
        }
    } catch (const std::exception &e) {
        std::fprintf(stderr, "build-ground: %s: corrupt PCD: %s\n", map_path, e.what());
        return 1;
    }
    std::vector<float> xyz(cloud.size() * 3);
    for (size_t i = 0; i < cloud.size(); i++) {
        xyz[3 * i] = cloud[i].x; xyz[3 * i + 1] = cloud[i].y; xyz[3 * i + 2] = cloud[i].z;
    }
    size_t nground = 0;
    pb_ground_t *g = gb_build(xyz.data(), cloud.size(), 3, &cfg, &nground);
    if (!g) { std::fprintf(stderr, "build-ground: %s: no finite points\n", map_path); return 1; }
    pb_err_t err = {""};
    int rc = pb_ground_save(g, out_path, &err);
    if (rc) std::fprintf(stderr, "build-ground: %s\n", err.msg);
    else if (!quiet) {
        double x0, y0, cell;
        int nx, ny;
        pb_ground_dims(g, &x0, &y0, &cell, &nx, &ny);
        std::fprintf(stderr, "build-ground: %zu map points -> %d x %d cells of %.2f m, %zu ground -> %s\n",
                     cloud.size(), nx, ny, cell, nground, out_path);
    }
    pb_ground_destroy(g);
    return rc ? 1 : 0;
}
