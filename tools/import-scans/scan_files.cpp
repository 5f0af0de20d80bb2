/* scan_files: see scan_files.h. */
#include "scan_files.h"
#include "pb_pcd.h"

#include <algorithm>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <cstring>

#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>

int parse_bin_fields(const char *list, BinLayout *out, pb_err_t *err)
{
    BinLayout r;
    r.x = r.y = r.z = r.i = -1;
    r.nfields = 0;
    const std::string s(list);
    size_t at = 0;
    for (;;) {
        size_t comma = s.find(',', at);
        std::string name = s.substr(at, comma == std::string::npos ? std::string::npos : comma - at);
        int *slot = name == "x" ? &r.x : name == "y" ? &r.y : name == "z" ? &r.z : name == "i" ? &r.i
                  : name == "ring" ? &r.ring : name == "t" ? &r.t : nullptr;
        if (!slot && name != "_") return pb_err_set(err, "'%s' is not a field (x, y, z, i, ring, t or _)", name.c_str());
        if (slot && *slot >= 0) return pb_err_set(err, "'%s' twice", name.c_str());
        if (r.nfields == 64) return pb_err_set(err, "more than 64 fields");
        if (slot) *slot = r.nfields;
        r.nfields++;
        if (comma == std::string::npos) break;
        at = comma + 1;
    }
    if (r.x < 0 || r.y < 0 || r.z < 0) return pb_err_set(err, "x, y and z are needed (got '%s')", list);
    *out = r;
    return 0;
}

static float median_of(std::vector<float> v)
{
    if (v.empty()) return NAN;
    std::nth_element(v.begin(), v.begin() + long(v.size() / 2), v.end());
    return v[v.size() / 2];
}

// Median distance between consecutive points when the file's floats are read n to a
// record with x y z at fx, fy, fz (over the first 20,000 records). A spinning LiDAR's
// points come in firing order, so neighbours in the file are neighbours in space; read
// with the wrong record size, x y z come from other fields and points jump.
static float consecutive_m(const std::vector<float> &f, int n, int fx, int fy, int fz)
{
    std::vector<float> d;
    size_t records = std::min(f.size() / size_t(n), size_t(20000));
    for (size_t k = 1; k < records; k++) {
        const float *a = &f[(k - 1) * n], *b = &f[k * n];
        float dx = b[fx] - a[fx], dy = b[fy] - a[fy], dz = b[fz] - a[fz];
        float dist = std::sqrt(dx * dx + dy * dy + dz * dz);
        if (std::isfinite(dist)) d.push_back(dist);
    }
    return median_of(d);
}

// A record size other than the layout's that fits the file far better (see
// consecutive_m), or 0. Only asked of the first scan.
static int better_record_size(const std::vector<float> &f, const BinLayout &L, float *given_m, float *other_m)
{
    *given_m = consecutive_m(f, L.nfields, L.x, L.y, L.z);
    if (!(*given_m > 1.0f)) return 0;   // neighbours already: the layout fits
    for (int n = 3; n <= 8; n++) {
        if (n == L.nfields || f.size() % size_t(n)) continue;
        float m = consecutive_m(f, n, 0, 1, 2);
        if (m < *given_m / 5) {
            *other_m = m;
            return n;
        }
    }
    return 0;
}

int read_bin(const std::string &path, const BinLayout &L, bool check_layout, Scan &s, pb_err_t *err)
{
    FILE *f = std::fopen(path.c_str(), "rb");
    if (!f) return pb_err_set(err, "%s: %s", path.c_str(), std::strerror(errno));
    std::fseek(f, 0, SEEK_END);
    long size = std::ftell(f);
    std::fseek(f, 0, SEEK_SET);
    if (size < 0) {
        std::fclose(f);
        return pb_err_set(err, "%s: cannot size the file", path.c_str());
    }
    const long rec = 4L * L.nfields;
    if (size % rec) {
        std::fclose(f);
        return pb_err_set(err, "%s: byte %ld: truncated point (file size %ld is not a multiple of %ld = %d float32 "
                          "a point; --bin-fields gives the fields)", path.c_str(), size - size % rec, size, rec,
                          L.nfields);
    }
    std::vector<float> buf(size_t(size) / 4);   // little-endian float32, as is this host
    size_t got = buf.empty() ? 0 : std::fread(buf.data(), size_t(rec), size_t(size / rec), f);
    std::fclose(f);
    if (got != size_t(size / rec))
        return pb_err_set(err, "%s: byte %zu: read error", path.c_str(), got * size_t(rec));
    float given_m, other_m;
    int other = check_layout ? better_record_size(buf, L, &given_m, &other_m) : 0;
    if (other)
        return pb_err_set(err, "%s: read as %d float32 a point, consecutive points lie %.2f m apart (median); as %d, "
                          "%.2f m: the file's points are likely %d floats each: give --bin-fields (e.g. "
                          "x,y,z,i,ring for nuScenes, x,y,z,i,ring,t for 6)", path.c_str(), L.nfields, given_m, other,
                          other_m, other);
    s.has_time = L.t >= 0;
    s.has_ring = L.ring >= 0;
    for (size_t k = 0; k < got; k++) {
        const float *p = &buf[size_t(L.nfields) * k];
        if (!std::isfinite(p[L.x]) || !std::isfinite(p[L.y]) || !std::isfinite(p[L.z])) { s.dropped++; continue; }
        s.x.push_back(p[L.x]); s.y.push_back(p[L.y]); s.z.push_back(p[L.z]);
        s.intensity.push_back(L.i >= 0 && std::isfinite(p[L.i]) ? p[L.i] : 0.f);
        if (L.ring >= 0) s.ring.push_back(p[L.ring] >= 0 && p[L.ring] < 255 ? uint8_t(p[L.ring]) : 255);
        if (L.t >= 0) {
            // seconds after the scan's time; a float32 cannot hold a UNIX time to the microsecond
            if (!(std::fabs(p[L.t]) <= 1.0f))
                return pb_err_set(err, "%s: byte %zu: point time %g s is not within a second of the scan's time "
                                  "(--bin-fields t is seconds after it)", path.c_str(), k * size_t(rec) + 4 * L.t,
                                  double(p[L.t]));
            s.offset_us.push_back(int32_t(std::lround(double(p[L.t]) * 1e6)));
        }
    }
    return 0;
}

static double field_value(const uint8_t *p, uint8_t datatype)
{
    switch (datatype) {
    case pcl::PCLPointField::INT8:    { int8_t v;   std::memcpy(&v, p, 1); return v; }
    case pcl::PCLPointField::UINT8:   { uint8_t v;  std::memcpy(&v, p, 1); return v; }
    case pcl::PCLPointField::INT16:   { int16_t v;  std::memcpy(&v, p, 2); return v; }
    case pcl::PCLPointField::UINT16:  { uint16_t v; std::memcpy(&v, p, 2); return v; }
    case pcl::PCLPointField::INT32:   { int32_t v;  std::memcpy(&v, p, 4); return v; }
    case pcl::PCLPointField::UINT32:  { uint32_t v; std::memcpy(&v, p, 4); return v; }
    case pcl::PCLPointField::FLOAT32: { float v;    std::memcpy(&v, p, 4); return v; }
    case pcl::PCLPointField::FLOAT64: { double v;   std::memcpy(&v, p, 8); return v; }
    default: return NAN;
    }
}

/* A double field's value as a float, NAN when a float cannot hold it. */
static float as_float(double v) { return std::fabs(v) <= FLT_MAX ? float(v) : NAN; }

int read_pcd(const std::string &path, Scan &s, pb_err_t *err)
{
    pcl::PCLPointCloud2 c;
    if (pb_pcd_check(path.c_str(), nullptr, err) != 0) return -1;
    try {
        if (pcl::io::loadPCDFile(path, c) < 0) return pb_err_set(err, "%s: not a readable PCD file", path.c_str());
    } catch (const std::exception &e) {
        return pb_err_set(err, "%s: corrupt PCD: %s", path.c_str(), e.what());
    }
    const pcl::PCLPointField *fx = nullptr, *fy = nullptr, *fz = nullptr, *fi = nullptr, *ft = nullptr, *fr = nullptr;
    double tscale = 0;  // field units -> us
    for (const auto &f : c.fields) {
        if (f.name == "x") fx = &f;
        else if (f.name == "y") fy = &f;
        else if (f.name == "z") fz = &f;
        else if (f.name == "intensity" || (f.name == "i" && !fi)) fi = &f;
        else if (f.name == "t") { ft = &f; tscale = 1e-3; }        // Ouster: ns after the sweep start
        else if (f.name == "time" && !ft) { ft = &f; tscale = 1e6; }  // Velodyne: s after the sweep start
        else if (f.name == "ring") fr = &f;
    }
    if (!fx || !fy || !fz) return pb_err_set(err, "%s: PCD has no x y z fields", path.c_str());
    s.has_time = ft != nullptr;
    s.has_ring = fr != nullptr;
    size_t n = size_t(c.width) * c.height;
    if (c.data.size() < n * c.point_step) return pb_err_set(err, "%s: PCD data shorter than its header says", path.c_str());
    for (size_t k = 0; k < n; k++) {
        size_t row = k / c.width, col = k % c.width;
        const uint8_t *p = c.data.data() + row * c.row_step + col * c.point_step;
        float x = as_float(field_value(p + fx->offset, fx->datatype)), y = as_float(field_value(p + fy->offset, fy->datatype)),
              z = as_float(field_value(p + fz->offset, fz->datatype));
        if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) { s.dropped++; continue; }
        s.x.push_back(x); s.y.push_back(y); s.z.push_back(z);
        float i = fi ? as_float(field_value(p + fi->offset, fi->datatype)) : 0.f;
        s.intensity.push_back(std::isfinite(i) ? i : 0.f);
        if (ft) {
            double t = field_value(p + ft->offset, ft->datatype) * tscale;
            s.offset_us.push_back(std::isfinite(t) && std::fabs(t) < 2e9 ? int32_t(std::llround(t)) : 0);
        }
        if (fr) {
            double r = field_value(p + fr->offset, fr->datatype);
            s.ring.push_back(r >= 0 && r < 255 ? uint8_t(r) : 255);
        }
    }
    return 0;
}

// See scan_files.h: firing order is judged on the steps between neighbours.
int times_from_azimuth(const std::string &path, Scan &s, bool ccw, double seam_rad, double sweep_us,
                              pb_err_t *err)
{
    const size_t n = s.x.size();
    if (n == 0) return 0;
    std::vector<double> az(n);
    for (size_t k = 0; k < n; k++) az[k] = std::atan2(double(s.y[k]), double(s.x[k]));
    if (std::isnan(seam_rad)) {
        const double small = 10 * M_PI / 180;
        double travel = 0;
        std::vector<float> steps(n - 1);
        for (size_t k = 1; k < n; k++) {
            double d = std::remainder(az[k] - az[k - 1], 2 * M_PI);
            steps[k - 1] = float(std::fabs(d));
            if (std::fabs(d) < small) travel += d;
        }
        const double need = 1.5 * M_PI, turns = travel / (2 * M_PI), median_deg = median_of(steps) * 180 / M_PI;
        if (!(median_deg < 5) || std::fabs(travel) < need)
            return pb_err_set(err, "%s: the points are not in firing order (median step %.1f deg, %.2f turns in file "
                              "order), so where the sweep starts is not known: give --seam-deg", path.c_str(),
                              n > 1 ? median_deg : 0.0, turns);
        if (ccw != (travel > 0))
            return pb_err_set(err, "%s: its points turn %s (%.1f turns in file order), not %s as --spin says",
                              path.c_str(), ccw ? "clockwise" : "counter-clockwise", std::fabs(turns),
                              ccw ? "ccw" : "cw");
        seam_rad = az[0];
    }
    s.offset_us.resize(n);
    for (size_t k = 0; k < n; k++) {
        double turn = (ccw ? az[k] - seam_rad : seam_rad - az[k]) / (2 * M_PI);
        turn -= std::floor(turn);
        s.offset_us[k] = int32_t(std::lround(turn * sweep_us));
    }
    s.has_time = true;
    return 0;
}

