/* gnss: u-blox receiver (UBX NAV-PVT, NMEA GGA/RMC fallback) -> GNSS_FIX.
 *   gnss --file FILE --out OUT.lcm          a capture of receiver bytes -> an LCM log
 *   gnss --file FILE [--lcm-url URL]        a capture -> the live bus (as fast as read)
 *   gnss --device /dev/ttyACM0 [--baud N]   a serial port -> the live bus
 * Thin shell: reading (file, raw tty), publishing, STATUS. Decoding and the fallback
 * rule are in core/gnss_driver.c. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "gnss_driver.h"
#include "pb_bus.h"
#include "pb_clock.h"
#include "pb_log.h"
#include "pb_opt.h"
#include "pb_signal.h"
#include "pb_status.h"
#include "portobello_gnss_fix_t.h"
#include "portobello_status_t.h"

#define PROG "gnss"
#define MAX_PRINTED_ERRORS 20

typedef struct {
    const char *source;            /* file or device path, for messages */
    const char *channel;
    int file_mode;                 /* --file: no host clock anywhere */
    pb_log_t *out;                 /* --out */
    pb_bus_t *bus;                 /* live bus (no --out) */
    pb_status_t *status;           /* live only */
    gnss_driver_t *drv;
    int64_t status_period;
    int64_t next_status;           /* --out: next STATUS at this fix time */
    int64_t module_time;           /* newest fix utime written */
    int64_t fixes_no_time;         /* dropped (--out) or stamped with host time (live) */
    int64_t printed_errors, write_errors;
    int64_t counters_sent[GNSS_C_COUNT];
    char last_error[512];
    int error_pending;             /* live: an error not yet given to pb_status */
    int quiet;
} app_t;

static void usage(FILE *f)
{
    fprintf(f,
        "usage: gnss --file FILE [--out OUT.lcm] | --device TTY [--baud N]  [options]\n"
        "Decodes a u-blox receiver's byte stream (UBX, NMEA and RTCM3 interleaved) into\n"
        "GNSS_FIX messages (portobello.gnss_fix_t): one per UBX-NAV-PVT; NMEA GGA/RMC are the\n"
        "fallback when no NAV-PVT arrives (see docs/gnss.md). Bad frames are counted in\n"
        "STATUS with a reason and the byte offset; decoding resynchronises on the next frame.\n"
        "  --file FILE          raw receiver bytes (a capture of the serial stream)\n"
        "  --out OUT.lcm        with --file: write GNSS_FIX and STATUS to this LCM log, stamped\n"
        "                       with the receiver's UTC time (fixes without it are dropped and\n"
        "                       counted); without --out, publish to the live bus\n"
        "  --device TTY         serial port (opened raw, 8N1, no flow control), live bus\n"
        "  --baud N             serial speed (default 38400, the u-blox F9 UART default)\n"
        "  --lcm-url URL        live bus (default $LCM_DEFAULT_URL or %s)\n"
        "  --channel NAME       fix channel (default GNSS_FIX)\n"
        "  --nmea-holdoff S     NMEA is suppressed while a NAV-PVT was seen within S seconds\n"
        "                       of receiver time (default 2.0)\n"
        "  --max-ubx-payload N  longest UBX payload accepted (default 8192)\n"
        "  --status-period S    STATUS every S seconds (default 1)\n"
        "  --quiet              no summary on stderr\n"
        "  -h, --help           this text\n", PB_DEFAULT_LCM_URL);
}

static void note_error(app_t *a, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void note_error(app_t *a, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(a->last_error, sizeof a->last_error, fmt, ap);
    va_end(ap);
    if (a->status && a->printed_errors < MAX_PRINTED_ERRORS) {
        pb_status_error(a->status, "%s", a->last_error);   /* sets last_error and prints it */
        if (++a->printed_errors == MAX_PRINTED_ERRORS)
            fprintf(stderr, PROG ": further errors are printed at most once per STATUS period\n");
    } else if (a->status) {
        a->error_pending = 1;   /* a noisy line must not flood stderr: see sync_status */
    } else if (a->printed_errors < MAX_PRINTED_ERRORS) {
        fprintf(stderr, PROG ": %s\n", a->last_error);
        if (++a->printed_errors == MAX_PRINTED_ERRORS)
            fprintf(stderr, PROG ": further errors are only counted (STATUS, summary)\n");
    }
}

/* STATUS for --out: the same message pb_status publishes, stamped with fix time. */
static void write_status(app_t *a, int8_t state)
{
    char *names[GNSS_C_COUNT + 1];
    int64_t values[GNSS_C_COUNT + 1];
    int n = 0;
    for (int c = 0; c < GNSS_C_COUNT; c++) {
        names[n] = (char *)gnss_counter_name((gnss_counter_t)c);
        values[n++] = gnss_driver_counter(a->drv, (gnss_counter_t)c);
    }
    names[n] = "fix_no_utc_dropped";
    values[n++] = a->fixes_no_time;
    portobello_status_t msg = {
        .utime = a->module_time, .module = PROG, .pid = 0, .state = state,
        .ninputs = 0, .inputs = NULL, .ncounters = n, .counter_names = names,
        .counter_values = values, .last_error = a->last_error,
    };
    int size = portobello_status_t_encoded_size(&msg);
    uint8_t *buf = malloc((size_t)size);
    pb_err_t err;
    if (!buf || portobello_status_t_encode(buf, 0, size, &msg) < 0 ||
        pb_log_write(a->out, a->module_time, "STATUS", buf, size, &err) != 0) {
        if (a->write_errors++ == 0) fprintf(stderr, PROG ": STATUS: %s\n", buf ? err.msg : "out of memory");
    }
    free(buf);
}

/* Live: brings pb_status's counters up to the driver's and publishes when due. */
static void sync_status(app_t *a)
{
    for (int c = 0; c < GNSS_C_COUNT; c++) {
        int64_t v = gnss_driver_counter(a->drv, (gnss_counter_t)c);
        if (v != a->counters_sent[c] || v == 0) {
            pb_status_count(a->status, gnss_counter_name((gnss_counter_t)c), v - a->counters_sent[c]);
            a->counters_sent[c] = v;
        }
    }
    if (a->error_pending) {
        pb_status_error(a->status, "%s", a->last_error);
        a->error_pending = 0;
    }
    int64_t dropped = pb_status_counter(a->status, "fix_host_time");
    pb_status_count(a->status, "fix_host_time", a->fixes_no_time - dropped);
}

static void on_fix(void *user, const gnss_fix_out_t *f)
{
    app_t *a = user;
    int64_t utime = f->utime;
    if (!f->has_utime) {
        a->fixes_no_time++;
        if (a->file_mode) {
            note_error(a, "%s: byte %lld: %s fix without a UTC date/time: not written", a->source,
                       (long long)f->offset, f->source == GNSS_SRC_NMEA ? "NMEA" : "NAV-PVT");
            return;
        }
        utime = pb_clock_wall_utime();   /* live: the host's receive time is the best there is */
    }
    portobello_gnss_fix_t m = {
        .utime = utime, .fix_type = f->fix_type, .num_sv = f->num_sv,
        .lat_deg = f->lat_deg, .lon_deg = f->lon_deg, .alt_m = f->alt_m, .alt_msl_m = f->alt_msl_m,
        .h_acc_m = f->h_acc_m, .v_acc_m = f->v_acc_m,
        .vel_ned_mps = { f->vel_ned_mps[0], f->vel_ned_mps[1], f->vel_ned_mps[2] },
        .speed_mps = f->speed_mps, .heading_deg = f->heading_deg, .heading_acc_deg = f->heading_acc_deg,
    };
    pb_err_t err;
    if (a->out) {
        /* STATUS heartbeats on fix time, before the first fix at or past their time. */
        if (a->module_time == 0) a->next_status = utime + a->status_period;
        while (a->module_time && utime >= a->next_status) {
            int64_t keep = a->module_time;
            a->module_time = a->next_status;
            write_status(a, PORTOBELLO_STATUS_T_STATE_OK);
            a->module_time = keep;
            a->next_status += a->status_period;
            if (utime - a->next_status > 100 * a->status_period)   /* a time jump: no flood */
                a->next_status = utime + a->status_period;
        }
        if (utime > a->module_time) a->module_time = utime;
        uint8_t buf[512];
        int n = portobello_gnss_fix_t_encode(buf, 0, (int)sizeof buf, &m);
        if (n < 0 || pb_log_write(a->out, utime, a->channel, buf, n, &err) != 0) {
            if (a->write_errors++ == 0) fprintf(stderr, PROG ": %s\n", n < 0 ? "encoding failed" : err.msg);
        }
    } else if (PB_PUBLISH(a->bus, a->channel, portobello_gnss_fix_t, &m, &err) != 0) {
        pb_status_count(a->status, "publish_failed", 1);
        pb_status_error(a->status, "%s", err.msg);
    }
}

static void on_error(void *user, gnss_counter_t c, int64_t offset, const char *detail)
{
    app_t *a = user;
    note_error(a, "%s: byte %lld: %s: %s", a->source, (long long)offset, gnss_counter_name(c), detail);
}

static speed_t baud_constant(long baud)
{
    switch (baud) {
    case 4800: return B4800;
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
    case 460800: return B460800;
    case 921600: return B921600;
    default: return 0;
    }
}

/* Opens a tty raw: 8N1, no flow control, no echo or line editing; reads return what
 * is there (VMIN 0, VTIME 0; poll() does the waiting). */
static int open_serial(const char *path, long baud, pb_err_t *err)
{
    int fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) return pb_err_set(err, "%s: %s", path, strerror(errno));
    struct termios t;
    if (tcgetattr(fd, &t) != 0) {
        pb_err_set(err, "%s: not a serial device: %s", path, strerror(errno));
        close(fd);
        return -1;
    }
    cfmakeraw(&t);
    t.c_cflag |= CLOCAL | CREAD;
    t.c_cflag &= ~(CSTOPB | CRTSCTS);
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 0;
    speed_t sp = baud_constant(baud);
    cfsetispeed(&t, sp);
    cfsetospeed(&t, sp);
    if (tcsetattr(fd, TCSANOW, &t) != 0) {
        pb_err_set(err, "%s: cannot set raw mode at %ld baud: %s", path, baud, strerror(errno));
        close(fd);
        return -1;
    }
    tcflush(fd, TCIFLUSH);
    return fd;
}

static void print_summary(app_t *a, const char *where)
{
    if (a->quiet) return;
    fprintf(stderr, PROG ": %s: %lld bytes; %lld UBX frames (%lld NAV-PVT), %lld NMEA sentences, "
            "%lld RTCM3 frames; %lld fixes from NAV-PVT, %lld from NMEA (%lld fills, %lld suppressed); "
            "%lld bytes skipped\n", where, (long long)gnss_driver_offset(a->drv),
            (long long)gnss_driver_counter(a->drv, GNSS_C_UBX_FRAMES),
            (long long)gnss_driver_counter(a->drv, GNSS_C_UBX_NAV_PVT),
            (long long)gnss_driver_counter(a->drv, GNSS_C_NMEA_SENTENCES),
            (long long)gnss_driver_counter(a->drv, GNSS_C_RTCM3_FRAMES),
            (long long)gnss_driver_counter(a->drv, GNSS_C_FIXES_UBX),
            (long long)gnss_driver_counter(a->drv, GNSS_C_FIXES_NMEA),
            (long long)gnss_driver_counter(a->drv, GNSS_C_NMEA_FILLS),
            (long long)gnss_driver_counter(a->drv, GNSS_C_NMEA_SUPPRESSED),
            (long long)gnss_driver_counter(a->drv, GNSS_C_SKIPPED_BYTES));
    int any = 0;
    for (int c = GNSS_C_FIRST_ERROR; c < GNSS_C_COUNT; c++) {
        int64_t v = gnss_driver_counter(a->drv, (gnss_counter_t)c);
        if (!v) continue;
        fprintf(stderr, "%s %s %lld", any ? "," : PROG ": errors:", gnss_counter_name((gnss_counter_t)c), (long long)v);
        any = 1;
    }
    if (a->fixes_no_time)
        fprintf(stderr, "%s %s %lld", any ? "," : PROG ":", a->file_mode ? "fixes without UTC time dropped" :
                "fixes stamped with host time", (long long)a->fixes_no_time);
    if (any || a->fixes_no_time) fputc('\n', stderr);
}

/* Reads fd until EOF (file) or a stop; live, STATUS is published on the wall clock. */
static int run_fd(app_t *a, int fd, int is_tty)
{
    uint8_t buf[65536];
    int64_t next_beat = pb_clock_wall_utime() + a->status_period;
    for (;;) {
        if (pb_signal_stop_requested()) return 0;
        if (is_tty) {
            struct pollfd p = { .fd = fd, .events = POLLIN };
            int r = poll(&p, 1, 100);
            if (r < 0 && errno != EINTR) { note_error(a, "%s: poll: %s", a->source, strerror(errno)); return -1; }
        }
        ssize_t n = read(fd, buf, sizeof buf);
        if (n > 0) gnss_driver_feed(a->drv, buf, (size_t)n);
        else if (n == 0 && !is_tty) return 0;
        else if (n < 0 && errno != EAGAIN && errno != EINTR) {
            /* EIO: the device went away (USB unplugged, pty closed). */
            note_error(a, "%s: read: %s", a->source, strerror(errno));
            return -1;
        }
        if (a->status) {
            int64_t now = pb_clock_wall_utime();
            if (now >= next_beat) {
                sync_status(a);
                pb_status_publish(a->status);
                next_beat = now + a->status_period;
            }
        }
    }
}

int main(int argc, char **argv)
{
    const char *file = NULL, *out = NULL, *device = NULL, *url = NULL;
    long baud = 38400, max_payload = 8192;
    double holdoff_s = 2.0, status_s = 1.0;
    app_t a = { .channel = "GNSS_FIX" };
    const pb_opt_t opts[] = {
        PB_OPT_STRING("file", &file), PB_OPT_STRING("out", &out), PB_OPT_STRING("device", &device),
        PB_OPT_LONG("baud", &baud, 1, 4000000), PB_OPT_STRING("lcm-url", &url), PB_OPT_STRING("channel", &a.channel),
        PB_OPT_DOUBLE("nmea-holdoff", &holdoff_s, 0, 3600), PB_OPT_LONG("max-ubx-payload", &max_payload, 92, 65535),
        PB_OPT_DOUBLE("status-period", &status_s, 0.01, 3600), PB_OPT_FLAG("quiet", &a.quiet, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse(PROG, opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    if (!baud_constant(baud)) {
        fprintf(stderr, PROG ": --baud: %ld is not one of 4800 9600 19200 38400 57600 115200 230400 460800 921600\n", baud);
        return 2;
    }
    if (!!file + !!device != 1) { fprintf(stderr, PROG ": give exactly one of --file and --device\n"); usage(stderr); return 2; }
    if (out && !file) { fprintf(stderr, PROG ": --out goes with --file\n"); return 2; }

    gnss_driver_config_t cfg;
    gnss_driver_config_default(&cfg);
    cfg.nmea_holdoff_ms = (int32_t)lround(holdoff_s * 1000.0);
    cfg.stream.max_ubx_payload = (size_t)max_payload;
    a.status_period = (int64_t)llround(status_s * 1e6);
    a.source = file ? file : device;
    a.file_mode = file != NULL;
    gnss_driver_handlers_t h = { .on_fix = on_fix, .on_error = on_error, .user = &a };
    a.drv = gnss_driver_create(&cfg, &h);
    if (!a.drv) { fprintf(stderr, PROG ": out of memory\n"); return 1; }

    pb_err_t err;
    int fd = -1, is_tty = 0;
    if (file) {
        fd = strcmp(file, "-") == 0 ? 0 : open(file, O_RDONLY | O_CLOEXEC);
        if (fd < 0) { fprintf(stderr, PROG ": %s: %s\n", file, strerror(errno)); gnss_driver_destroy(a.drv); return 1; }
    } else {
        fd = open_serial(device, baud, &err);
        if (fd < 0) { fprintf(stderr, PROG ": %s\n", err.msg); gnss_driver_destroy(a.drv); return 1; }
        is_tty = 1;
    }
    if (out) {
        a.out = pb_log_open_write(out, &err);
        if (!a.out) { fprintf(stderr, PROG ": %s\n", err.msg); close(fd); gnss_driver_destroy(a.drv); return 1; }
    } else {
        a.bus = pb_bus_create_live(url, &err);
        if (!a.bus) { fprintf(stderr, PROG ": %s\n", err.msg); close(fd); gnss_driver_destroy(a.drv); return 1; }
        a.status = pb_status_create(a.bus, PROG, a.status_period);
        pb_status_set_state(a.status, PORTOBELLO_STATUS_T_STATE_OK);
    }
    pb_signal_install();

    int rc = run_fd(&a, fd, is_tty);
    if (fd > 0) close(fd);
    if (is_tty) gnss_driver_stop(a.drv);
    else gnss_driver_finish(a.drv);   /* a frame cut short at the end of a file is reported now */

    int8_t state = rc == 0 ? PORTOBELLO_STATUS_T_STATE_STOPPING : PORTOBELLO_STATUS_T_STATE_ERROR;
    int status = rc == 0 ? 0 : 1;
    if (a.out) {
        write_status(&a, state);
        if (pb_log_close(a.out, &err) != 0) { fprintf(stderr, PROG ": %s\n", err.msg); status = 1; }
        if (a.write_errors) status = 1;
    } else {
        sync_status(&a);
        pb_status_set_state(a.status, state);
        pb_status_publish(a.status);
        pb_status_destroy(a.status);
        pb_bus_destroy(a.bus);
    }
    print_summary(&a, a.source);
    gnss_driver_destroy(a.drv);
    return status;
}
