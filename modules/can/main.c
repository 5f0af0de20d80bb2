/* can: the vehicle's CAN bus -> CAN_FRAME and VEHICLE_SPEED.
 *   can --iface can0 [--lcm-url URL]           live SocketCAN (raw socket, listen-only)
 *   can --candump FILE.log [--out OUT.lcm]     a `candump -l` capture (- stdin), to a log or live
 *   can --replay IN.lcm --out OUT.lcm          CAN_FRAME events of a log (simdrive, import-candump)
 *   can --from-bus [--lcm-url URL]             CAN_FRAME on the live bus (a log played by lcm-logplayer)
 * The shell: options, input, publishing, STATUS. Decoding is can_speed.c, frame
 * layout can_kernel.c, the DBC can_dbc.c. */
#include <errno.h>
#include <stdarg.h>
#include <libgen.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "core/can_dbc.h"
#include "core/can_kernel.h"
#include "can_socket.h"
#include "core/can_speed.h"
#include "pb_bus.h"
#include "pb_candump.h"
#include "pb_clock.h"
#include "pb_opt.h"
#include "pb_signal.h"
#include "pb_status.h"
#include "pb_vehicle.h"
#include "portobello_can_frame_t.h"
#include "portobello_status_t.h"
#include "portobello_vehicle_speed_t.h"

#define PATH_MAX_WHERE 4200
#define LOUD_ERRORS 20          /* problems printed one by one; later ones are counted */

typedef struct {
    pb_bus_t *bus;
    pb_status_t *status;
    can_speed_dec_t *dec;
    const can_dbc_t *dbc;
    const char *frame_channel, *speed_channel;
    int publish_frames;                 /* candump and live: CAN_FRAME out as well */
    int64_t problems, frames, speeds;
    int64_t verdicts[CAN_V_COUNT];
    int64_t time_backwards;
    pb_candump_buses_t buses;           /* --candump's interfaces */
    uint32_t last_dropped;
    int realtime;                       /* live --candump: pace frames by their times */
    int64_t rt_frame0, rt_wall0;
} app_t;

static void usage(FILE *f)
{
    fprintf(f,
        "usage: can (--iface IFACE | --candump FILE.log [--out OUT.lcm] | --replay IN.lcm --out OUT.lcm | --from-bus)\n"
        "           [--vehicle FILE.yaml] [--dbc FILE.dbc] [--bus N] [--checksum auto|toyota|none]\n"
        "           [--yaw-max-age-ms MS] [--lcm-url URL]\n"
        "\n"
        "Reads the vehicle's CAN bus and publishes CAN_FRAME (every frame, as received) and\n"
        "VEHICLE_SPEED (speed, four wheel speeds, yaw rate) decoded through the vehicle's DBC.\n"
        "One VEHICLE_SPEED per wheel-speed frame (Toyota WHEEL_SPEEDS 0x0AA: speed = mean of\n"
        "the wheels) and per speed frame (SPEED 0x0B4); the newest yaw rate (KINEMATICS 0x024)\n"
        "within --yaw-max-age-ms rides along; in reverse (GEAR_PACKET 0x3BC, \"R\" in the DBC's\n"
        "value table, at most 5 s old) the speed is negative. Frames of a wrong length, with a bad checksum,\n"
        "of unknown ids, error and remote frames are counted in STATUS by reason, never fatal.\n"
        "  --iface IFACE        live: a SocketCAN interface (raw socket, kernel receive\n"
        "                       timestamps; never writes: put the interface in listen-only\n"
        "                       mode with `ip link set IFACE type can ... listen-only on`)\n"
        "  --candump FILE       a `candump -l` log (- for stdin, e.g. `candump -L can0 | can\n"
        "                       --candump -`): CAN_FRAME + VEHICLE_SPEED to --out, or to the\n"
        "                       live bus without --out (times from the lines)\n"
        "  --realtime           live --candump: publish each frame at its time after the first\n"
        "                       (gaps capped at 1 s) instead of as fast as possible\n"
        "  --replay IN.lcm      offline: decode the CAN_FRAME events of IN; VEHICLE_SPEED to --out\n"
        "  --from-bus           live: decode the CAN_FRAME messages on the bus (a drive played\n"
        "                       with lcm-logplayer) to VEHICLE_SPEED, as --replay does offline\n"
        "  --out OUT.lcm        the log --candump / --replay write (with STATUS)\n"
        "  --vehicle FILE       vehicle file whose dbc: is used (default vehicles/prius2017.yaml)\n"
        "  --dbc FILE           a DBC instead of the vehicle's\n"
        "  --bus N              bus whose frames are decoded (default 0; -1 every bus)\n"
        "  --checksum KIND      auto (default: toyota for a DBC named toyota_*, as opendbc\n"
        "                       does), toyota or none: checks messages with a CHECKSUM signal\n"
        "  --yaw-max-age-ms MS  newest yaw rate attached if at most this old (default 50)\n"
        "  --frame-channel CH   CAN frame channel (default CAN_FRAME)\n"
        "  --speed-channel CH   speed channel (default VEHICLE_SPEED)\n"
        "  --lcm-url URL        live bus (default $LCM_DEFAULT_URL or %s)\n"
        "  -h, --help           this text\n", PB_DEFAULT_LCM_URL);
}

/* A bad input: counted under its reason; printed for the first few only. */
static void problem(app_t *a, const char *reason, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void problem(app_t *a, const char *reason, const char *fmt, ...)
{
    pb_status_count(a->status, reason, 1);
    if (++a->problems > LOUD_ERRORS && a->problems % 10000 != 0) return;
    char msg[600];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    pb_status_error(a->status, "%s%s", msg, a->problems == LOUD_ERRORS ? " (further problems are counted in STATUS only)" : "");
}

static void publish_frame(app_t *a, const can_rx_t *f)
{
    portobello_can_frame_t m = {
        .utime = f->utime, .bus = (int16_t)f->bus, .id = (int32_t)f->id, .extended = f->extended,
        .rtr = f->rtr, .error = f->error, .fd = f->fd, .len = f->len, .data = (uint8_t *)f->data,
    };
    pb_err_t err;
    if (PB_PUBLISH(a->bus, a->frame_channel, portobello_can_frame_t, &m, &err) != 0)
        pb_status_error(a->status, "%s", err.msg);
}

/* Every frame from every input goes through here. */
static void handle_frame(app_t *a, const can_rx_t *f, const char *where)
{
    a->frames++;
    pb_status_count(a->status, "frames", 1);
    if (a->publish_frames) publish_frame(a, f);
    can_speed_t s;
    int back = 0;
    can_verdict_t v = can_speed_decode(a->dec, f, &s, &back);
    a->verdicts[v]++;
    if (back) {
        a->time_backwards++;
        problem(a, "time_backwards", "%s: frame time %lld us is before the previous frame's", where, (long long)f->utime);
    }
    switch (v) {
    case CAN_V_SPEED: {
        pb_status_count(a->status, "speed", 1);
        portobello_vehicle_speed_t m = {
            .utime = s.utime, .source = (char *)s.source, .speed_mps = s.speed_mps,
            .has_wheel_speeds = s.has_wheel_speeds, .has_yaw_rate = s.has_yaw_rate, .yaw_rate_rps = s.yaw_rate_rps,
        };
        memcpy(m.wheel_speed_mps, s.wheel_speed_mps, sizeof m.wheel_speed_mps);
        pb_err_t err;
        if (PB_PUBLISH(a->bus, a->speed_channel, portobello_vehicle_speed_t, &m, &err) != 0)
            pb_status_error(a->status, "%s", err.msg);
        a->speeds++;
        break;
    }
    case CAN_V_DECODED: pb_status_count(a->status, "decoded", 1); break;
    case CAN_V_OTHER_BUS: pb_status_count(a->status, "other_bus", 1); break;
    case CAN_V_UNKNOWN_ID: pb_status_count(a->status, "unknown_id", 1); break;   /* normal on a real bus */
    case CAN_V_BAD_LENGTH: {
        const can_message_t *m = can_dbc_find(a->dbc, f->id, f->extended);
        problem(a, "bad_length", "%s: id 0x%03X %s: %u bytes, the DBC says %u", where, (unsigned)f->id,
                m ? m->name : "?", f->len, m ? m->length : 0);
        break;
    }
    case CAN_V_BAD_CHECKSUM:
        problem(a, "bad_checksum", "%s: id 0x%03X: checksum byte 0x%02X does not match (Toyota checksum 0x%02X)", where,
                (unsigned)f->id, f->data[f->len - 1], can_checksum_toyota(f->id, f->data, f->len));
        break;
    case CAN_V_ERROR_FRAME:
        problem(a, "error_frame", "%s: bus error frame, class 0x%08X", where, (unsigned)f->id);
        break;
    case CAN_V_REMOTE_FRAME: pb_status_count(a->status, "remote_frame", 1); break;
    default: break;
    }
}

/* --replay: CAN_FRAME events of a log. */
static void on_can_frame(const pb_msg_t *msg, void *user)
{
    app_t *a = user;
    portobello_can_frame_t m;
    char where[96];
    snprintf(where, sizeof where, "%s event %lld", msg->channel, (long long)pb_bus_events_read(a->bus));
    if (portobello_can_frame_t_decode(msg->data, 0, msg->len, &m) < 0) {
        problem(a, "undecodable", "%s: %d bytes do not decode as can_frame_t", where, msg->len);
        return;
    }
    can_rx_t f = { .utime = m.utime, .bus = m.bus, .id = (uint32_t)m.id, .extended = m.extended,
                   .rtr = m.rtr, .error = m.error, .fd = m.fd };
    int maxlen = m.fd ? 64 : 8;
    if (m.len < 0 || m.len > maxlen || m.id < 0 || (uint32_t)m.id > (m.extended || m.error ? 0x1FFFFFFFu : 0x7FFu)) {
        problem(a, "bad_frame", "%s: id 0x%X / length %d out of range for a %s frame", where, (unsigned)m.id, m.len,
                m.fd ? "CAN FD" : "classic");
        portobello_can_frame_t_decode_cleanup(&m);
        return;
    }
    f.len = (uint8_t)m.len;
    memcpy(f.data, m.data, (size_t)m.len);
    portobello_can_frame_t_decode_cleanup(&m);
    pb_status_input_time(a->status, msg->channel, f.utime);
    handle_frame(a, &f, where);
}

/* --realtime: waits until the frame's time, counted from the first frame. */
static void pace(app_t *a, int64_t frame_utime)
{
    if (!a->rt_wall0) { a->rt_wall0 = pb_clock_wall_utime(); a->rt_frame0 = frame_utime; return; }
    int64_t due = a->rt_wall0 + (frame_utime - a->rt_frame0), now = pb_clock_wall_utime();
    if (due > now + 1000000) due = now + 1000000;     /* a gap in the capture: at most 1 s */
    if (due > now) {
        struct timespec ts = { (time_t)((due - now) / 1000000), (long)((due - now) % 1000000) * 1000 };
        nanosleep(&ts, NULL);
    }
}

/* --candump: every line; a bad line is counted and skipped. */
static int run_candump(app_t *a, const char *path, pb_err_t *err)
{
    int is_stdin = strcmp(path, "-") == 0;
    FILE *in = is_stdin ? stdin : fopen(path, "rb");
    if (!in) return pb_err_set(err, "%s: %s", path, strerror(errno));
    char *line = NULL;
    size_t cap = 0;
    ssize_t got;
    long lineno = 0;
    int rc = 0;
    while ((got = getline(&line, &cap, in)) >= 0 && !pb_signal_stop_requested()) {
        lineno++;
        pb_candump_frame_t c;
        size_t col = 0;
        int r = pb_candump_parse(line, (size_t)got, &c, &col);
        if (r == PB_CANDUMP_BLANK) continue;
        if (r != PB_CANDUMP_FRAME) {
            static const char *const reasons[] = { "", "line_bad_time", "line_bad_iface", "line_bad_id",
                                                   "line_bad_data", "line_bad_length", "line_trailing", "line_can_xl" };
            problem(a, -r < 8 ? reasons[-r] : "line_bad", "%s:%ld:%zu: %s", path, lineno, col, pb_candump_strerror(r));
            continue;
        }
        int bus = pb_candump_bus(&a->buses, c.iface, NULL);
        if (bus < 0) {
            problem(a, "too_many_interfaces", "%s:%ld: more than %d interfaces not named canN", path, lineno, PB_CANDUMP_MAX_NAMED);
            continue;
        }
        can_rx_t f = { .utime = c.utime, .bus = bus, .id = c.id, .extended = c.extended, .rtr = c.rtr,
                       .error = c.error, .fd = c.fd, .len = c.len };
        memcpy(f.data, c.data, sizeof f.data);
        /* Log time never goes backwards: a late frame is stamped at the newest time.
         * On a live bus this only fires due timers (wall clock). */
        if (pb_bus_is_replay(a->bus)) {
            int64_t now = pb_bus_now(a->bus);
            if (pb_bus_advance(a->bus, f.utime > now ? f.utime : now, err) != 0) { rc = -1; break; }
        } else {
            if (a->realtime) pace(a, f.utime);
            pb_bus_advance(a->bus, 0, NULL);
        }
        pb_status_input_time(a->status, "candump", f.utime);
        char where[PATH_MAX_WHERE];
        snprintf(where, sizeof where, "%s:%ld", path, lineno);
        handle_frame(a, &f, where);
    }
    if (rc == 0 && ferror(in)) rc = pb_err_set(err, "%s: read error: %s", path, strerror(errno));
    free(line);
    if (!is_stdin) fclose(in);
    return rc;
}

/* --iface: live SocketCAN. */
static int run_socket(app_t *a, const char *iface, pb_err_t *err)
{
    int fd = can_socket_open(iface, err);
    if (fd < 0) return -1;
    int bus = pb_candump_can_index(iface);
    if (bus < 0) bus = PB_CANDUMP_NAMED_BUS_BASE;
    fprintf(stderr, "can: reading %s (bus %d), listen-only\n", iface, bus);
    int rc = 0;
    while (!pb_signal_stop_requested()) {
        can_rx_t f;
        can_kernel_extra_t ex;
        int r = can_socket_read(fd, bus, 50, &f, &ex, err);
        pb_bus_advance(a->bus, 0, NULL);
        if (r == 2) continue;
        if (r == -100) { rc = -1; break; }
        if (r < 0) { problem(a, "bad_kernel_frame", "%s: %s", iface, can_kernel_strerror(r)); continue; }
        if (r == CAN_K_NO_TIMESTAMP) {
            f.utime = pb_clock_wall_utime();
            problem(a, "no_kernel_timestamp", "%s: frame without a kernel timestamp: wall clock used", iface);
        }
        if (ex.has_dropped && ex.dropped != a->last_dropped) {
            pb_status_count(a->status, "kernel_dropped", (int64_t)(uint32_t)(ex.dropped - a->last_dropped));
            pb_status_error(a->status, "%s: the kernel dropped %u frames (receive queue full)", iface,
                            (unsigned)(ex.dropped - a->last_dropped));
            a->last_dropped = ex.dropped;
        }
        pb_status_input_time(a->status, iface, f.utime);
        handle_frame(a, &f, iface);
    }
    close(fd);
    return rc;
}

int main(int argc, char **argv)
{
    const char *url = NULL, *in = NULL, *out = NULL, *candump = NULL, *iface = NULL;
    int from_bus = 0;
    const char *vehicle_path = PB_SOURCE_DIR "/vehicles/prius2017.yaml", *dbc_path = NULL;
    static const char *const checksums[] = { "auto", "toyota", "none" };
    int checksum = 0;
    app_t a = { .frame_channel = "CAN_FRAME", .speed_channel = "VEHICLE_SPEED" };
    can_speed_config_t cfg;
    can_speed_config_default(&cfg);
    const pb_opt_t opts[] = {
        PB_OPT_STRING("replay", &in), PB_OPT_STRING("out", &out), PB_OPT_STRING("candump", &candump),
        PB_OPT_STRING("iface", &iface), PB_OPT_STRING("vehicle", &vehicle_path), PB_OPT_STRING("dbc", &dbc_path),
        PB_OPT_INT("bus", &cfg.bus, -1, 32767), PB_OPT_CHOICE("checksum", &checksum, checksums, 3),
        PB_OPT_MICROS("yaw-max-age-ms", &cfg.yaw_max_age_us, 0, 1e6, 1000), PB_OPT_STRING("lcm-url", &url),
        PB_OPT_FLAG("realtime", &a.realtime, 1), PB_OPT_FLAG("from-bus", &from_bus, 1),
        PB_OPT_STRING("frame-channel", &a.frame_channel), PB_OPT_STRING("speed-channel", &a.speed_channel), PB_OPT_END,
    };
    int parsed = pb_opt_parse("can", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    if (!!in + !!candump + !!iface + from_bus != 1) { fprintf(stderr, "can: give exactly one of --iface, --candump, --replay, --from-bus\n"); usage(stderr); return 2; }
    if (from_bus && out) { fprintf(stderr, "can: --from-bus publishes to the live bus; --out goes with --candump or --replay\n"); return 2; }
    if (a.realtime && (!candump || out)) { fprintf(stderr, "can: --realtime goes with --candump to the live bus (no --out)\n"); return 2; }
    if (in && !out) { fprintf(stderr, "can: --replay needs --out OUT.lcm\n"); return 2; }
    if (iface && out) { fprintf(stderr, "can: --out goes with --candump or --replay, not --iface\n"); return 2; }

    pb_err_t err;
    static pb_vehicle_t veh;
    if (!dbc_path) {
        if (pb_vehicle_load(vehicle_path, &veh, &err) != 0) { fprintf(stderr, "can: %s\n", err.msg); return 1; }
        if (!veh.dbc[0]) { fprintf(stderr, "can: %s: the vehicle file names no dbc\n", vehicle_path); return 1; }
        dbc_path = veh.dbc;
    }
    can_dbc_t *dbc = can_dbc_load(dbc_path, &err);
    if (!dbc) { fprintf(stderr, "can: %s\n", err.msg); return 1; }
    if (checksum == 1) cfg.checksum = CAN_CHECKSUM_TOYOTA;
    else if (checksum == 0) {
        char tmp[512];
        snprintf(tmp, sizeof tmp, "%s", dbc_path);
        cfg.checksum = strncmp(basename(tmp), "toyota_", 7) == 0 ? CAN_CHECKSUM_TOYOTA : CAN_CHECKSUM_NONE;
    }
    a.dbc = dbc;
    a.dec = can_speed_create(dbc, &cfg, &err);
    if (!a.dec) { fprintf(stderr, "can: %s: %s\n", dbc_path, err.msg); can_dbc_destroy(dbc); return 1; }

    if (in) a.bus = pb_bus_create_replay(in, out, &err);
    else if (candump && out) a.bus = pb_bus_create_source(out, &err);
    else a.bus = pb_bus_create_live(url, &err);
    if (!a.bus) { fprintf(stderr, "can: %s\n", err.msg); can_speed_destroy(a.dec); can_dbc_destroy(dbc); return 1; }
    a.publish_frames = !in && !from_bus;     /* the frames are on the bus already */
    pb_signal_install();
    a.status = pb_status_create(a.bus, "can", 1000000);
    pb_status_set_state(a.status, PORTOBELLO_STATUS_T_STATE_OK);

    int rc;
    if (in || from_bus) {
        pb_bus_subscribe(a.bus, a.frame_channel, on_can_frame, &a);
        if (from_bus) fprintf(stderr, "can: decoding %s on %s\n", a.frame_channel, pb_lcm_url(url));
        rc = pb_bus_run(a.bus, &err);
    } else if (candump) {
        rc = run_candump(&a, candump, &err);
    } else {
        rc = run_socket(&a, iface, &err);
    }
    pb_status_finish(a.status, rc ? err.msg : NULL);
    fprintf(stderr, "can: %lld frames, %lld VEHICLE_SPEED (dbc %s, bus %d, checksum %s): "
            "%lld other bus, %lld unknown id, %lld bad length, %lld bad checksum, %lld error, %lld remote, "
            "%lld time backwards, %lld other problems\n",
            (long long)a.frames, (long long)a.speeds, dbc_path, cfg.bus,
            cfg.checksum == CAN_CHECKSUM_TOYOTA ? "toyota" : "none",
            (long long)a.verdicts[CAN_V_OTHER_BUS], (long long)a.verdicts[CAN_V_UNKNOWN_ID],
            (long long)a.verdicts[CAN_V_BAD_LENGTH], (long long)a.verdicts[CAN_V_BAD_CHECKSUM],
            (long long)a.verdicts[CAN_V_ERROR_FRAME], (long long)a.verdicts[CAN_V_REMOTE_FRAME],
            (long long)a.time_backwards,
            (long long)(a.problems - a.verdicts[CAN_V_BAD_LENGTH] - a.verdicts[CAN_V_BAD_CHECKSUM] -
                        a.verdicts[CAN_V_ERROR_FRAME] - a.time_backwards));
    pb_status_destroy(a.status);
    pb_bus_destroy(a.bus);
    can_speed_destroy(a.dec);
    can_dbc_destroy(dbc);
    return rc == 0 ? 0 : 1;
}
