/* Unit tests of the occlusion map (modules/occlusion/core/occ_map): synthetic sweeps of a
 * 64 x 1024 roof LiDAR (+-16.6 deg) over flat ground, cast analytically against boxes.
 *  - a car that comes alongside: the roof LiDAR sees only its upper part, and the space
 *    below was seen free from afar before it came; a pedestrian across the street seen
 *    through its lower body must be hidden, not visible (the fill below the lowest beam);
 *  - a wall: hidden behind it, visible beside it, unknown where never observed;
 *  - a box that drives away is cleared at the next sweep; a post that comes back into space
 *    just cleared hides at once;
 *  - an edge inside a voxel: a ray passing 10 cm beside a wall's edge, through the 0.2 m
 *    voxel that holds the edge, is visible; 3 cm inside the edge it is hidden;
 *  - a top inside a voxel: a ray 6 cm over a low box's top, through the voxel that holds
 *    it, is visible; 2 cm below the top it is hidden;
 *  - an edge in the next voxel (the halo): a thin pole 27 m away that one column of beams
 *    hits just before a voxel's side hides a ray through its part in the next voxel,
 *    which no return reached; a ray past the pole is visible;
 *  - a voxel's shape kept: a pole the LiDAR no longer sees (a sign above the eye's line
 *    hides it from the roof) still hides what is behind it, and a ray beside it through
 *    the same voxel stays visible (its columns, not the whole voxel). */
#include <cmath>
#include <vector>

#include "occlusion/core/occ_map.h"
#include "pb_check.h"

struct box_t { double lo[3], hi[3]; };

static const double LIDAR_Z = 1.95, LIDAR_X = 1.10;   /* base -> sensor, as the Prius */
static const double EYE[3] = { 1.05, 0.37, 1.17 };    /* seat eye in base */

/* Nearest t > 0 where the ray o + t d meets the ground (z = 0) or a box; INFINITY if none within 100 m. */
static double cast(const double o[3], const double d[3], const std::vector<box_t> &boxes)
{
    double best = d[2] < -1e-9 ? -o[2] / d[2] : INFINITY;
    for (const box_t &b : boxes) {
        double t0 = 0, t1 = INFINITY;
        for (int i = 0; i < 3; i++) {
            if (std::fabs(d[i]) < 1e-12) {
                if (o[i] < b.lo[i] || o[i] > b.hi[i]) t0 = INFINITY;
                continue;
            }
            double a = (b.lo[i] - o[i]) / d[i], c = (b.hi[i] - o[i]) / d[i];
            t0 = std::max(t0, std::min(a, c));
            t1 = std::min(t1, std::max(a, c));
        }
        if (t0 <= t1 && t0 > 0) best = std::min(best, t0);
    }
    return best <= 100 ? best : INFINITY;
}

/* One sweep from the car at (cx, 0), heading +x, into the map. */
static void sweep(occ_map_t *m, double cx, const std::vector<box_t> &boxes)
{
    std::vector<float> x, y, z;
    std::vector<uint16_t> oi;
    double o[3] = { cx + LIDAR_X, 0, LIDAR_Z };
    for (int c = 0; c < 1024; c++) {
        double az = 2 * M_PI * c / 1024;
        for (int r = 0; r < 64; r++) {
            double el = (16.6 - 33.2 * r / 63) * M_PI / 180;
            double d[3] = { std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el) };
            double t = cast(o, d, boxes);
            if (!std::isfinite(t)) continue;
            x.push_back((float)(o[0] + t * d[0])); y.push_back((float)(o[1] + t * d[1])); z.push_back((float)(o[2] + t * d[2]));
            oi.push_back(0);
        }
    }
    double origins[1][3] = { { o[0], o[1], o[2] } };
    occ_sweep_t sw = {};
    sw.n = (int)x.size(); sw.x = x.data(); sw.y = y.data(); sw.z = z.data();
    sw.origin_index = oi.data(); sw.norigins = 1; sw.origins = origins;
    for (int i = 0; i < 3; i++) sw.mid_origin[i] = o[i];
    const double I[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 };
    for (int i = 0; i < 9; i++) sw.mid_rot[i] = I[i];
    sw.car[0] = cx; sw.car[1] = 0; sw.car[2] = 0;
    occ_map_integrate(m, &sw, nullptr);
}

static int8_t ask(const occ_map_t *m, double cx, double sx, double sy, double sz, float *occ = nullptr)
{
    double eye[3] = { cx + EYE[0], EYE[1], EYE[2] }, base[3] = { cx, 0, 0 };
    float px = (float)sx, py = (float)sy, pz = (float)sz, om;
    int8_t st;
    occ_map_query(m, eye, base, 0, &px, &py, &pz, 1, &st, &om);
    if (occ) *occ = om;
    return st;
}

static occ_config_t config()
{
    occ_config_t c;
    c.ego_x0 = -1.04; c.ego_x1 = 3.50; c.ego_half_width = 0.88; c.ego_height = 1.47;
    return c;
}

/* A map (default configuration) of the sweeps from the car approaching the boxes: at
 * x = -6, -5, ... 0 m. */
static occ_map_t *approached(const std::vector<box_t> &boxes)
{
    occ_config_t c = config();
    occ_map_t *m = occ_map_create(&c);
    for (double cx = -6; cx <= 0; cx += 1.0) sweep(m, cx, boxes);
    return m;
}

/* A car alongside (left, 2.2 to 4.0 m out, 0.2 to 1.65 m high) arrives after the road beside
 * was seen free from 15 m back; a pedestrian 15 m across the street behind it. */
static void test_car_alongside(bool fill)
{
    occ_config_t c = config();
    if (!fill) c.fill_radius_m = 0;
    occ_map_t *m = occ_map_create(&c);
    std::vector<box_t> none, car = { { { -1.0, 2.2, 0.2 }, { 3.6, 4.0, 1.65 } } };
    for (double cx = -15; cx < 0; cx += 1.0) sweep(m, cx, none);
    /* before the car comes: the pedestrian is visible (the space was observed free) */
    CHECK(ask(m, -1.0, 1.0, 15, 1.0) == OCC_VISIBLE);
    for (int k = 0; k < 3; k++) sweep(m, 0, car);
    float om = NAN;
    int8_t st = ask(m, 0, 1.0, 15, 1.0, &om);
    if (fill) {
        CHECK(st == OCC_HIDDEN);            /* through the car's unseen lower body */
        CHECK(om > 1.5 && om < 4.0);        /* the occluder is the car, 1.8 to 3.6 m from the eye */
        CHECK(ask(m, 0, 1.0, 15, 2.6) == OCC_HIDDEN);  /* the head of a tall agent over the roof line: the roof hides it */
    } else {
        CHECK(st == OCC_VISIBLE);           /* without the fill: the error this guards against */
    }
    /* the car has gone: the fill was for its sweeps only */
    for (int k = 0; k < 3; k++) sweep(m, 0, none);
    CHECK(ask(m, 0, 1.0, 15, 1.0) == OCC_VISIBLE);
    occ_map_destroy(m);
}

static void test_wall_and_unknown()
{
    /* a wall 10 m ahead, 4 m wide, 3 m high */
    std::vector<box_t> wall = { { { 12.0, -2.0, 0.0 }, { 12.3, 2.0, 3.0 } } };
    occ_map_t *m = approached(wall);
    CHECK(ask(m, 0, 20, 0, 1.0) == OCC_HIDDEN);       /* behind the wall */
    CHECK(ask(m, 0, 20, 8, 1.0) == OCC_VISIBLE);      /* beside it, seen free */
    CHECK(ask(m, 0, 8, 0, 1.0) == OCC_VISIBLE);       /* in front of it */
    /* far behind the wall: the LiDAR never saw there, but the wall is on the way: hidden */
    CHECK(ask(m, 0, 30, 0.5, 1.0) == OCC_HIDDEN);
    /* beyond range: unknown, never visible */
    CHECK(ask(m, 0, 60, 20, 1.0) == OCC_UNKNOWN);
    occ_map_destroy(m);
    /* nothing integrated yet: unknown, not visible */
    occ_config_t c = config();
    m = occ_map_create(&c);
    CHECK(ask(m, 0, 20, 8, 1.0) == OCC_UNKNOWN);
    occ_map_destroy(m);
}

static void test_moving_box_clears()
{
    occ_config_t c = config();
    occ_map_t *m = occ_map_create(&c);
    std::vector<box_t> none, bus = { { { 10.0, 3.0, 0.3 }, { 22.0, 5.5, 3.4 } } };
    for (double cx = -5; cx < 0; cx += 1.0) sweep(m, cx, none);
    for (int k = 0; k < 3; k++) sweep(m, 0, bus);
    CHECK(ask(m, 0, 30, 12, 1.0) == OCC_HIDDEN);      /* the bus between eye and pedestrian */
    sweep(m, 0, none);
    CHECK(ask(m, 0, 30, 12, 1.0) == OCC_VISIBLE);     /* gone at the next sweep */
    occ_map_destroy(m);
}

/* What a sweep hits hides at once, even where the tree still holds the space free: a post
 * seen for one sweep, gone the next (its voxels missed), back the one after (one hit after
 * a miss leaves OctoMap's log-odds below occupied). From two viewpoints in turn, real
 * surfaces seen at a grazing angle go through the same (one view hits, the other sees past). */
static void test_hit_after_a_miss()
{
    occ_config_t c = config();
    occ_map_t *m = occ_map_create(&c);
    /* a post 8 cm square in the middle of one voxel column, 9 m ahead and 3 m left: what hides
     * it is that voxel alone (the halo of its returns stays inside it) */
    std::vector<box_t> none, post = { { { 10.06, 3.06, 0.0 }, { 10.14, 3.14, 2.5 } } };
    const double ex = EYE[0], ey = EYE[1], px = 10.10, py = 3.10;
    const double sx = ex + 2 * (px - ex), sy = ey + 2 * (py - ey);   /* behind the post, seen through its middle */
    for (double cx = -5; cx <= 0; cx += 1.0) sweep(m, cx, none);
    sweep(m, 0, post);
    CHECK(ask(m, 0, sx, sy, 1.2) == OCC_HIDDEN);
    sweep(m, 0, none);
    CHECK(ask(m, 0, sx, sy, 1.2) == OCC_VISIBLE);
    sweep(m, 0, post);
    CHECK(ask(m, 0, sx, sy, 1.2) == OCC_HIDDEN);
    occ_map_destroy(m);
}

/* Asks for a sample at x = 20 whose eye ray crosses the plane x = 10 (a box's front face)
 * at y = t, 1.2 m up (across), or straight ahead at z = t (over). */
static int ask_through_face(occ_map_t *m, double t, bool over)
{
    const double s = (20 - EYE[0]) / (10 - EYE[0]);
    return over ? ask(m, 0, 20, EYE[1], EYE[2] + (t - EYE[2]) * s) : ask(m, 0, 20, EYE[1] + (t - EYE[1]) * s, 1.2);
}

static void test_edge_inside_a_voxel()
{
    /* a wall ahead whose left edge (y = 1.05) lies inside the voxels y 1.0 .. 1.2 */
    std::vector<box_t> wall = { { { 10.0, -2.0, 0.0 }, { 10.3, 1.05, 3.0 } } };
    occ_map_t *m = approached(wall);
    CHECK(ask_through_face(m, 1.15, false) == OCC_VISIBLE);   /* 10 cm past the edge (the whole voxel would hide it) */
    CHECK(ask_through_face(m, 1.02, false) == OCC_HIDDEN);    /* 3 cm inside it */
    CHECK(ask_through_face(m, 0.5, false) == OCC_HIDDEN);     /* well inside */
    occ_map_destroy(m);
    /* a low box ahead, its top (z = 1.03) inside the voxels z 1.0 .. 1.2 */
    std::vector<box_t> box = { { { 10.0, -1.0, 0.0 }, { 12.0, 1.0, 1.03 } } };
    m = approached(box);
    CHECK(ask_through_face(m, 1.09, true) == OCC_VISIBLE);    /* 6 cm over the top (the whole voxel would hide it) */
    CHECK(ask_through_face(m, 1.01, true) == OCC_HIDDEN);     /* 2 cm below it */
    occ_map_destroy(m);
}

static void test_edge_in_the_next_voxel()
{
    /* column 6 of the sweep from the car at 0 (azimuth 2 pi 6 / 1024) meets the pole's face
     * (x = 27.43) at y = 0.97, in the voxels y 0.8 .. 1.0; the pole reaches to y = 1.08, in
     * the next voxels, where column 7 (y = 1.13) passes beside it: no return there */
    std::vector<box_t> pole = { { { 27.43, 0.95, 0.0 }, { 27.53, 1.08, 3.0 } } };
    occ_config_t c = config();
    occ_map_t *m = occ_map_create(&c);
    for (int k = 0; k < 3; k++) sweep(m, 0, pole);
    const double ex = EYE[0], ey = EYE[1];
    auto sample_y = [&](double yt) { return ey + (yt - ey) * (35 - ex) / (27.43 - ex); };
    CHECK(ask(m, 0, 35, sample_y(1.03), 0.6) == OCC_HIDDEN);    /* through the pole, in the voxel no return reached */
    CHECK(ask(m, 0, 35, sample_y(0.97), 0.6) == OCC_HIDDEN);    /* through the pole where the beam hit it */
    CHECK(ask(m, 0, 35, sample_y(1.15), 0.6) == OCC_VISIBLE);   /* 7 cm past it */
    occ_map_destroy(m);
}

static void test_shape_kept()
{
    /* a thin pole 10 m ahead, y 1.01 .. 1.07, in the voxels y 1.0 .. 1.2; then a sign (z 1.45
     * .. 2.6, at x 5 .. 5.5) over the road between: the roof LiDAR's beams to the pole's
     * middle meet the sign, the eye's line (1.1 to 1.2 m high) passes under it */
    std::vector<box_t> pole = { { { 10.05, 1.01, 0.0 }, { 10.11, 1.07, 3.0 } } };
    std::vector<box_t> both = pole;
    both.push_back({ { 5.0, -1.0, 1.45 }, { 5.5, 3.0, 2.6 } });
    occ_config_t c = config();
    occ_map_t *m = occ_map_create(&c);
    for (double cx = -3; cx <= 0; cx += 1.0) sweep(m, cx, pole);
    sweep(m, 0, both);
    const double ex = EYE[0], ey = EYE[1];
    auto sample_y = [&](double yt) { return ey + (yt - ey) * (20 - ex) / (10.08 - ex); };
    CHECK(ask(m, 0, 20, sample_y(1.02), 1.1) == OCC_HIDDEN);    /* through the pole, not seen in this sweep */
    CHECK(ask(m, 0, 20, sample_y(1.16), 1.1) == OCC_VISIBLE);   /* 9 cm beside it, through its voxel */
    occ_map_destroy(m);
}

int main()
{
    test_shape_kept();
    test_edge_in_the_next_voxel();
    test_edge_inside_a_voxel();
    test_car_alongside(true);
    test_car_alongside(false);
    test_wall_and_unknown();
    test_moving_box_clears();
    test_hit_after_a_miss();
    return pb_check_report("test_occ_map");
}
