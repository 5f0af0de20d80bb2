// pose_files: the readers of pose, time and calib files (see pose_files.h).
#include "pose_files.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>

// ---------------------------------------------------------------- text helpers

// Seconds as a decimal string -> microseconds, exact up to 6 fractional
// digits and rounded half up beyond (MulRan stamps have 7). An integer of 16
// digits is microseconds, of 19 nanoseconds (rounded half up; MulRan's CSV
// files and scan names). Falls back to strtod for exponents. Returns 0 or -1.
int parse_time_us(const std::string &s, int64_t *out)
{
    size_t i = 0;
    bool neg = false;
    if (i < s.size() && (s[i] == '-' || s[i] == '+')) neg = s[i++] == '-';
    size_t digits = 0;
    while (i + digits < s.size() && std::isdigit((unsigned char)s[i + digits])) digits++;
    if (i + digits == s.size() && (digits == 16 || digits == 19)) {
        errno = 0;
        int64_t v = std::strtoll(s.c_str() + i, nullptr, 10);   /* 19 digits fit below 9.22e18 only */
        if (errno == ERANGE || v < 0) return -1;
        if (digits == 19) v = v / 1000 + (v % 1000 >= 500 ? 1 : 0);
        *out = neg ? -v : v;
        return 0;
    }
    int64_t sec = 0, us = 0;
    int nint = 0, nfrac = 0, round_digit = 0;
    for (; i < s.size() && std::isdigit((unsigned char)s[i]); i++, nint++) {
        if (nint >= 12) return -1;
        sec = sec * 10 + (s[i] - '0');
    }
    if (i < s.size() && s[i] == '.') {
        for (i++; i < s.size() && std::isdigit((unsigned char)s[i]); i++, nfrac++) {
            if (nfrac < 6) us = us * 10 + (s[i] - '0');
            else if (nfrac == 6) round_digit = s[i] - '0';
        }
    }
    if (i != s.size() || nint + nfrac == 0) {
        char *end;
        double v = std::strtod(s.c_str(), &end);
        if (*end || end == s.c_str() || !std::isfinite(v) || std::fabs(v) > 1e12) return -1;
        *out = std::llround(v * 1e6);
        return 0;
    }
    for (int k = nfrac; k < 6; k++) us *= 10;
    int64_t v = sec * 1000000 + us + (round_digit >= 5 ? 1 : 0);
    *out = neg ? -v : v;
    return 0;
}

// Tokens separated by white space or commas (CSV files).
static void split_ws(const std::string &line, std::vector<std::string> &tok)
{
    tok.clear();
    size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (std::isspace((unsigned char)line[i]) || line[i] == ',')) i++;
        size_t j = i;
        while (j < line.size() && !std::isspace((unsigned char)line[j]) && line[j] != ',') j++;
        if (j > i) tok.push_back(line.substr(i, j - i));
        i = j;
    }
}

static bool to_double(const std::string &s, double *v)
{
    char *end;
    errno = 0;
    *v = std::strtod(s.c_str(), &end);
    return end != s.c_str() && *end == '\0' && errno != ERANGE && std::isfinite(*v);
}

// ---------------------------------------------------------------- poses

// Calls fn(lineno, tokens, line) for each line of a text file with tokens (blank
// lines skipped). fn returns 0 to go on, 1 to stop (done), -1 on error (err set).
// Returns 0 at the end of the file or when fn stopped, -1 on an error.
template <typename Fn>
static int for_each_line(const char *path, pb_err_t *err, Fn fn)
{
    std::ifstream in(path);
    if (!in) return pb_err_set(err, "%s: %s", path, std::strerror(errno));
    std::string line;
    std::vector<std::string> tok;
    long lineno = 0;
    while (std::getline(in, line)) {
        lineno++;
        split_ws(line, tok);
        if (tok.empty()) continue;
        int r = fn(lineno, tok, line);
        if (r < 0) return -1;
        if (r > 0) return 0;
    }
    if (in.bad()) return pb_err_set(err, "%s: read error", path);
    return 0;
}

static int rotation_from_rows(const double *m12, Eigen::Isometry3d *T)
{
    Eigen::Matrix3d R;
    R << m12[0], m12[1], m12[2], m12[4], m12[5], m12[6], m12[8], m12[9], m12[10];
    if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-2 || R.determinant() < 0)
        return -1;
    Eigen::Quaterniond q(R);    // KITTI rows carry ~6 digits: re-orthonormalise through the quaternion
    q.normalize();
    T->setIdentity();
    T->linear() = q.toRotationMatrix();
    T->translation() = Eigen::Vector3d(m12[3], m12[7], m12[11]);
    return 0;
}

const char *format_name(PoseFormat f)
{
    return f == FMT_KITTI ? "KITTI (12)" : f == FMT_TUM ? "TUM (8)" : "timed KITTI (13)";
}

// Reads a KITTI, TUM or timed KITTI file into poses (and the times of the last two).
// Returns 0 or -1.
int read_poses(const char *path, std::vector<Eigen::Isometry3d> &poses, std::vector<int64_t> &times,
                      PoseFormat *fmt, pb_err_t *err)
{
    *fmt = FMT_NONE;
    int rc = for_each_line(path, err, [&](long lineno, const std::vector<std::string> &tok, const std::string &) {
        if (tok[0][0] == '#') return 0;
        PoseFormat f = tok.size() == 12 ? FMT_KITTI : tok.size() == 8 ? FMT_TUM : tok.size() == 13 ? FMT_KITTI_TIMED
                                                                                                   : FMT_NONE;
        if (f == FMT_NONE)
            return pb_err_set(err, "%s:%ld: expected 12 numbers (KITTI 3x4), 8 (TUM t x y z qx qy qz qw) or 13 (t and "
                              "a 3x4), got %zu", path, lineno, tok.size());
        if (*fmt == FMT_NONE) *fmt = f;
        if (f != *fmt)
            return pb_err_set(err, "%s:%ld: %zu numbers, but the file started as %s", path, lineno, tok.size(),
                              format_name(*fmt));
        const size_t t0 = f == FMT_KITTI ? 0 : 1;   /* the first number after the time */
        double v[12];
        for (size_t k = t0; k < tok.size(); k++)
            if (!to_double(tok[k], &v[k - t0]))
                return pb_err_set(err, "%s:%ld: column %zu: not a finite number: '%s'", path, lineno, k + 1,
                                  tok[k].c_str());
        int64_t us = 0;
        if (t0 && parse_time_us(tok[0], &us) != 0)
            return pb_err_set(err, "%s:%ld: column 1: bad time '%s' (seconds, or an integer of 16 digits for "
                              "microseconds or 19 for nanoseconds)", path, lineno, tok[0].c_str());
        Eigen::Isometry3d T;
        if (f != FMT_TUM) {
            if (rotation_from_rows(v, &T) != 0)
                return pb_err_set(err, "%s:%ld: the 3x3 part is not a rotation matrix", path, lineno);
        } else {
            Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
            if (q.norm() < 1e-6) return pb_err_set(err, "%s:%ld: zero quaternion", path, lineno);
            q.normalize();
            T.setIdentity();
            T.linear() = q.toRotationMatrix();
            T.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
        }
        if (t0) {
            if (!times.empty() && us <= times.back())
                return pb_err_set(err, "%s:%ld: time %s is not after the line before's", path, lineno, tok[0].c_str());
            times.push_back(us);
        }
        poses.push_back(T);
        return 0;
    });
    if (rc != 0) return -1;
    if (poses.empty()) return pb_err_set(err, "%s: no poses", path);
    return 0;
}

int read_calib_tr(const char *path, Eigen::Isometry3d *Tr, pb_err_t *err)
{
    bool found = false;
    int rc = for_each_line(path, err, [&](long lineno, const std::vector<std::string> &tok, const std::string &) {
        if (tok[0] != "Tr:" && tok[0] != "Tr_velo_to_cam:" && tok[0] != "Tr_velo_cam:") return 0;
        if (tok.size() != 13)
            return pb_err_set(err, "%s:%ld: %s expects 12 numbers, got %zu", path, lineno, tok[0].c_str(),
                              tok.size() - 1);
        double v[12];
        for (int k = 0; k < 12; k++)
            if (!to_double(tok[k + 1], &v[k]))
                return pb_err_set(err, "%s:%ld: column %d: not a finite number: '%s'", path, lineno, k + 2,
                                  tok[k + 1].c_str());
        if (rotation_from_rows(v, Tr) != 0)
            return pb_err_set(err, "%s:%ld: the 3x3 part of Tr is not a rotation matrix", path, lineno);
        found = true;
        return 1;
    });
    if (rc != 0) return -1;
    if (!found) return pb_err_set(err, "%s: no 'Tr:' line (velodyne -> camera transform)", path);
    return 0;
}

int read_times(const char *path, std::vector<int64_t> &times, pb_err_t *err)
{
    int rc = for_each_line(path, err, [&](long lineno, const std::vector<std::string> &tok, const std::string &line) {
        if (tok[0][0] == '#') return 0;
        int64_t us;
        if (tok.size() != 1 || parse_time_us(tok[0], &us) != 0)
            return pb_err_set(err, "%s:%ld: expected one time (seconds, or an integer of 16 digits for microseconds or "
                              "19 for nanoseconds), got '%s'", path, lineno, line.c_str());
        times.push_back(us);
        return 0;
    });
    if (rc != 0) return -1;
    if (times.empty()) return pb_err_set(err, "%s: no times", path);
    return 0;
}

