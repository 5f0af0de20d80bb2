/* picture: see picture.h. */
#include "picture.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <png.h>

namespace {
struct Canvas {
    int w, h;
    double x0, y1, res;   /* world x of column 0, world y of row 0 (top), metres per pixel */
    std::vector<uint8_t> rgb;
    void put(int c, int r, const uint8_t col[3])
    {
        if (c < 0 || r < 0 || c >= w || r >= h) return;
        std::memcpy(&rgb[3 * ((size_t)r * w + c)], col, 3);
    }
    void dot(const Eigen::Vector3d &p, int radius, const uint8_t col[3])
    {
        int c = (int)std::floor((p.x() - x0) / res), r = (int)std::floor((y1 - p.y()) / res);
        for (int dr = -radius; dr <= radius; dr++)
            for (int dc = -radius; dc <= radius; dc++)
                if (dr * dr + dc * dc <= radius * radius) put(c + dc, r + dr, col);
    }
    void line(const Eigen::Vector3d &a, const Eigen::Vector3d &b, int radius, const uint8_t col[3])
    {
        int steps = std::max(1, (int)std::ceil((b - a).head<2>().norm() / res));
        for (int i = 0; i <= steps; i++) dot(a + (b - a) * ((double)i / steps), radius, col);
    }
    void path(const std::vector<Eigen::Vector3d> &p, int radius, const uint8_t col[3])
    {
        for (size_t i = 1; i < p.size(); i++)
            if (p[i - 1].allFinite() && p[i].allFinite()) line(p[i - 1], p[i], radius, col);   /* NaN: between two drives */
    }
};
}  // namespace

struct pb_picture {
    Canvas cv;
    std::vector<uint32_t> count;   /* the map's points a pixel */
};

pb_picture_t *pb_picture_begin(const pb_picture_layers_t *L)
{
    if (L->after.empty()) return nullptr;
    /* the drive's surroundings: the trajectory's extent and 40 m around (the map reaches
     * the sensor's range, mostly sparse far returns) */
    Eigen::Vector2d lo = L->after[0].head<2>(), hi = lo;
    for (const auto &p : L->after)
        if (p.allFinite()) { lo = lo.cwiseMin(p.head<2>()); hi = hi.cwiseMax(p.head<2>()); }
    lo -= Eigen::Vector2d(40, 40);
    hi += Eigen::Vector2d(40, 40);
    pb_picture_t *pic = new pb_picture_t();
    Canvas &cv = pic->cv;
    cv.res = std::max(0.2, std::max(hi.x() - lo.x(), hi.y() - lo.y()) / 2000);
    cv.w = (int)std::ceil((hi.x() - lo.x()) / cv.res);
    cv.h = (int)std::ceil((hi.y() - lo.y()) / cv.res);
    cv.x0 = lo.x();
    cv.y1 = hi.y();
    pic->count.assign((size_t)cv.w * cv.h, 0);
    return pic;
}

void pb_picture_add(pb_picture_t *pic, const float *xyz, size_t n, size_t stride)
{
    const Canvas &cv = pic->cv;
    for (size_t i = 0; i < n; i++) {
        const float *p = xyz + i * stride;
        int c = (int)std::floor((p[0] - cv.x0) / cv.res), r = (int)std::floor((cv.y1 - p[1]) / cv.res);
        if (c >= 0 && r >= 0 && c < cv.w && r < cv.h) pic->count[(size_t)r * cv.w + c]++;
    }
}

void pb_picture_end(pb_picture_t *p) { delete p; }

int pb_picture_write(pb_picture_t *pic, const pb_picture_layers_t *L, const char *png_path, double *m_per_px,
                     pb_err_t *err)
{
    if (!pic) return pb_err_set(err, "picture: no trajectory"), -1;
    Canvas &cv = pic->cv;
    const std::vector<uint32_t> &count = pic->count;
    uint32_t top = std::max<uint32_t>(1, *std::max_element(count.begin(), count.end()));
    cv.rgb.assign((size_t)cv.w * cv.h * 3, 255);
    for (size_t i = 0; i < count.size(); i++) {
        if (!count[i]) continue;
        /* grey by log density: single returns light, walls and kerbs dark */
        double v = std::log1p((double)count[i]) / std::log1p((double)top);
        uint8_t g = (uint8_t)(215 - 175 * v);
        cv.rgb[3 * i] = cv.rgb[3 * i + 1] = cv.rgb[3 * i + 2] = g;
    }
    static const uint8_t orange[3] = {245, 140, 20}, blue[3] = {20, 80, 220}, green[3] = {0, 170, 60},
                         red[3] = {215, 25, 30}, magenta[3] = {200, 0, 200}, violet[3] = {100, 0, 170};
    for (size_t i = 0; i + 2 < L->removed.size(); i += 3)
        cv.dot(Eigen::Vector3d(L->removed[i], L->removed[i + 1], L->removed[i + 2]), 0, magenta);
    for (size_t i = 0; i + 2 < L->objects.size(); i += 3)
        cv.dot(Eigen::Vector3d(L->objects[i], L->objects[i + 1], L->objects[i + 2]), 1, violet);
    for (const auto &f : L->fixes) cv.dot(f, 1, red);
    cv.path(L->before, 1, orange);
    cv.path(L->after, 1, blue);
    for (const auto &l : L->loops) cv.line(l.first, l.second, 1, green);
    for (const auto &l : L->loops) { cv.dot(l.first, 4, green); cv.dot(l.second, 4, green); }

    FILE *f = std::fopen(png_path, "wb");
    if (!f) return pb_err_set(err, "%s: %s", png_path, std::strerror(errno)), -1;
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    if (!png || !info || setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        std::fclose(f);
        return pb_err_set(err, "%s: PNG write failed", png_path), -1;
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)cv.w, (png_uint_32)cv.h, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int r = 0; r < cv.h; r++) png_write_row(png, &cv.rgb[(size_t)r * cv.w * 3]);
    png_write_end(png, nullptr);
    png_destroy_write_struct(&png, &info);
    if (std::fclose(f) != 0) return pb_err_set(err, "%s: %s", png_path, std::strerror(errno)), -1;
    *m_per_px = cv.res;
    return 0;
}
