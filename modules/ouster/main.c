/* ouster: Ouster lidar + IMU UDP packets -> LIDAR_SCAN and IMU on the bus.
 *   ouster --metadata JSON [--lcm-url URL]                live: UDP ports from the metadata
 *   ouster --pcap FILE --metadata JSON --out OUT.lcm      offline: a capture -> an LCM log
 * The core (ouster_driver, ouster_packet, ouster_meta, ouster_pcap) does no I/O of its
 * own beyond the pcap file; this shell owns sockets, the bus, the log and STATUS. */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "core/ouster_driver.h"
#include "core/ouster_meta.h"
#include "core/ouster_pcap.h"
#include "pb_bus.h"
#include "pb_log.h"
#include "pb_opt.h"
#include "pb_signal.h"
#include "pb_status.h"
#include "portobello_status_t.h"

#define PROG "ouster"
#define STATUS_PERIOD_US 1000000

typedef struct {
    const char *lidar_channel, *imu_channel;
    ouster_driver_t *drv;
    /* offline */
    pb_log_t *log;
    ouster_pcap_t *pcap;
    int64_t last_event_utime;
    int write_failed;
    pb_err_t write_err;
    /* live */
    pb_bus_t *bus;
    pb_status_t *status;
    int64_t status_synced[32];
    int64_t err_seq_seen, warn_seq_seen;
    uint8_t *enc;
    int enc_cap;
    int64_t scans, imus;
} app_t;

static void usage(FILE *f)
{
    fprintf(f,
        "usage: ouster --metadata JSON [--pcap FILE --out OUT.lcm] [options]\n"
        "Decodes Ouster lidar and IMU UDP packets (profiles LEGACY, RNG19_RFL8_SIG16_NIR16 and its\n"
        "_DUAL variant, RNG15_RFL8_NIR8; IMU profile LEGACY) with the beam intrinsics of the\n"
        "sensor's metadata JSON, and publishes one LIDAR_SCAN range image per frame and one IMU\n"
        "per IMU packet.\n"
        "  --metadata JSON      sensor metadata (flat or nested layout) - required\n"
        "  --pcap FILE          read a libpcap capture instead of live UDP (IPv4 fragments are\n"
        "                       reassembled); needs --out\n"
        "  --out OUT.lcm        offline: LCM log to write (LIDAR_SCAN, IMU, STATUS), event time =\n"
        "                       capture time of the packet that completed the message\n"
        "  --lidar-port N       UDP port of lidar packets (default: metadata udp_port_lidar, else 7502)\n"
        "  --imu-port N         UDP port of IMU packets (default: metadata udp_port_imu, else 7503)\n"
        "  --return 1|2         which return of the DUAL profile to publish (default 1)\n"
        "  --signal auto|on|off signal and near-IR in LIDAR_SCAN; auto: when rows x cols <= 64 x 1024\n"
        "                       (keeps a sweep under 600 KB) - default auto\n"
        "  --no-sensor-check    accept packets whose init_id / prod_sn differ from the metadata\n"
        "  --lidar-channel CH   default LIDAR_SCAN;  --imu-channel CH  default IMU\n"
        "  --lcm-url URL        live bus (default $LCM_DEFAULT_URL or %s)\n"
        "  --quiet              no summary on stderr\n"
        "  -h, --help           this text\n"
        "Time: utime = sensor timestamp mapped to UNIX time (see docs/ouster.md): sensor time plus the\n"
        "smallest (receive - sensor) offset seen over 10 s; sensor timestamps already in UNIX time\n"
        "(PTP/GPS) are used as they are. Bad packets are counted in STATUS by reason, never fatal.\n",
        PB_DEFAULT_LCM_URL);
}

static int encode(app_t *a, int size, int (*enc)(void *, int, int, const void *), const void *msg)
{
    if (size > a->enc_cap) {
        uint8_t *b = realloc(a->enc, size);
        if (!b) return -1;
        a->enc = b;
        a->enc_cap = size;
    }
    return enc(a->enc, 0, size, msg);
}

static void emit(app_t *a, const char *channel, int n, int64_t recv_utime)
{
    pb_err_t err;
    if (n < 0) { fprintf(stderr, PROG ": %s: encoding failed\n", channel); return; }
    if (a->log) {
        /* event times never go backwards (a capture can hold reordered records) */
        int64_t t = recv_utime > a->last_event_utime ? recv_utime : a->last_event_utime;
        a->last_event_utime = t;
        if (!a->write_failed && pb_log_write(a->log, t, channel, a->enc, n, &err) != 0) {
            a->write_failed = 1;
            a->write_err = err;
        }
    } else if (pb_bus_publish(a->bus, channel, a->enc, n, &err) != 0) {
        pb_status_error(a->status, "%s", err.msg);
    }
}

static void on_scan(const portobello_lidar_scan_t *s, int64_t recv_utime, void *user)
{
    app_t *a = user;
    int n = encode(a, portobello_lidar_scan_t_encoded_size(s),
                   (int (*)(void *, int, int, const void *))portobello_lidar_scan_t_encode, s);
    emit(a, a->lidar_channel, n, recv_utime);
    a->scans++;
}

static void on_imu(const portobello_imu_t *m, int64_t recv_utime, void *user)
{
    app_t *a = user;
    int n = encode(a, portobello_imu_t_encoded_size(m), (int (*)(void *, int, int, const void *))portobello_imu_t_encode, m);
    emit(a, a->imu_channel, n, recv_utime);
    a->imus++;
}

/* ---------------------------------------------------------------- offline STATUS */

static void offline_status(app_t *a, int64_t utime, int8_t state, const char *extra_error)
{
    const char *const *dn;
    const int64_t *dv;
    int nd = ouster_driver_counters(a->drv, &dn, &dv);
    const int64_t *pv = ouster_pcap_counters(a->pcap);
    char *names[64];
    int64_t values[64];
    int k = 0;
    for (int i = 0; i < nd; i++) { names[k] = (char *)dn[i]; values[k++] = dv[i]; }
    for (int i = 0; i < OUSTER_PCAP_NCOUNTERS; i++) { names[k] = (char *)ouster_pcap_counter_names[i]; values[k++] = pv[i]; }
    int64_t dseq, pseq;
    const char *derr = ouster_driver_last_error(a->drv, &dseq);
    const char *pwarn = ouster_pcap_last_warning(a->pcap, &pseq);
    const char *last = extra_error ? extra_error : derr[0] ? derr : pwarn;
    portobello_input_status_t inputs[2] = {
        { .channel = "udp_lidar", .count = ouster_driver_counter(a->drv, "lidar_packets"), .age_s = -1, .rate_hz = 0 },
        { .channel = "udp_imu", .count = ouster_driver_counter(a->drv, "imu_packets"), .age_s = -1, .rate_hz = 0 },
    };
    portobello_status_t st = {
        .utime = utime, .module = PROG, .pid = 0, .state = state, .ninputs = 2, .inputs = inputs,
        .ncounters = k, .counter_names = names, .counter_values = values, .last_error = (char *)last,
    };
    int n = encode(a, portobello_status_t_encoded_size(&st), (int (*)(void *, int, int, const void *))portobello_status_t_encode, &st);
    emit(a, "STATUS", n, utime);
}

static int64_t rejects(const ouster_driver_t *d)
{
    const char *const *names;
    const int64_t *v;
    int n = ouster_driver_counters(d, &names, &v);
    int64_t sum = 0;
    for (int i = 0; i < n; i++) if (strncmp(names[i], "rejected_", 9) == 0) sum += v[i];
    return sum;
}

static int run_pcap(app_t *a, const char *pcap_path, const char *out_path, int lidar_port, int imu_port, int quiet)
{
    pb_err_t err;
    a->pcap = ouster_pcap_open(pcap_path, &err);
    if (!a->pcap) { fprintf(stderr, PROG ": %s\n", err.msg); return 1; }
    a->log = pb_log_open_write(out_path, &err);
    if (!a->log) { fprintf(stderr, PROG ": %s\n", err.msg); ouster_pcap_close(a->pcap); return 1; }

    ouster_udp_t u;
    int rc, status = 0;
    int64_t other_ports = 0, next_status = 0, now = 0, warn_seq = 0, err_seq = 0;
    while ((rc = ouster_pcap_next(a->pcap, &u, &err)) == 1 && !pb_signal_stop_requested()) {
        now = u.utime;
        if (u.dst_port == lidar_port) ouster_driver_lidar_packet(a->drv, u.payload, u.len, u.utime);
        else if (u.dst_port == imu_port) ouster_driver_imu_packet(a->drv, u.payload, u.len, u.utime);
        else other_ports++;
        int64_t s;
        const char *m = ouster_driver_last_error(a->drv, &s);
        if (s != err_seq && !quiet) fprintf(stderr, PROG ": %s: record %lld: %s\n", pcap_path, (long long)u.record, m);
        err_seq = s;
        m = ouster_pcap_last_warning(a->pcap, &s);
        if (s != warn_seq && !quiet) fprintf(stderr, PROG ": %s\n", m);
        warn_seq = s;
        if (next_status == 0) next_status = now + STATUS_PERIOD_US;
        if (now >= next_status) {
            offline_status(a, now, rejects(a->drv) ? PORTOBELLO_STATUS_T_STATE_DEGRADED : PORTOBELLO_STATUS_T_STATE_OK, NULL);
            next_status += STATUS_PERIOD_US * ((now - next_status) / STATUS_PERIOD_US + 1);
        }
    }
    ouster_driver_flush(a->drv, now);
    if (rc < 0) {
        fprintf(stderr, PROG ": %s\n", err.msg);
        offline_status(a, now, PORTOBELLO_STATUS_T_STATE_ERROR, err.msg);
        status = 1;
    } else {
        offline_status(a, now, PORTOBELLO_STATUS_T_STATE_STOPPING, NULL);
    }
    if (a->write_failed) { fprintf(stderr, PROG ": %s\n", a->write_err.msg); status = 1; }
    if (pb_log_close(a->log, &err) != 0) { fprintf(stderr, PROG ": %s\n", err.msg); status = 1; }
    if (!quiet || status) {
        fprintf(stderr, PROG ": %lld LIDAR_SCAN (%lld incomplete), %lld IMU written to %s; %lld lidar and %lld IMU "
                "packets, %lld rejected, %lld datagrams on other ports\n",
                (long long)a->scans, (long long)ouster_driver_counter(a->drv, "frames_incomplete"), (long long)a->imus,
                out_path, (long long)ouster_driver_counter(a->drv, "lidar_packets"),
                (long long)ouster_driver_counter(a->drv, "imu_packets"), (long long)rejects(a->drv),
                (long long)other_ports);
    }
    ouster_pcap_close(a->pcap);
    return status;
}

/* ---------------------------------------------------------------- live */

static int64_t wall_utime(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static int udp_socket(int port, pb_err_t *err)
{
    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    if (fd < 0) return pb_err_set(err, "socket: %s", strerror(errno));
    int one = 1, buf = 8 << 20;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &buf, sizeof buf);
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port), .sin_addr.s_addr = htonl(INADDR_ANY) };
    if (bind(fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
        pb_err_set(err, "UDP port %d: %s", port, strerror(errno));
        close(fd);
        return -1;
    }
    return fd;
}

static void live_sync_status(app_t *a)
{
    const char *const *names;
    const int64_t *v;
    int n = ouster_driver_counters(a->drv, &names, &v);
    for (int i = 0; i < n && i < 32; i++) {
        if (v[i] != a->status_synced[i] || strncmp(names[i], "rejected_", 9) != 0) {
            pb_status_count(a->status, names[i], v[i] - a->status_synced[i]);
            a->status_synced[i] = v[i];
        }
    }
    int64_t seq;
    const char *m = ouster_driver_last_error(a->drv, &seq);
    if (seq != a->err_seq_seen) { pb_status_error(a->status, "%s", m); a->err_seq_seen = seq; }
    pb_status_set_state(a->status, rejects(a->drv) ? PORTOBELLO_STATUS_T_STATE_DEGRADED : PORTOBELLO_STATUS_T_STATE_OK);
}

static int run_live(app_t *a, const char *url, int lidar_port, int imu_port, int quiet)
{
    pb_err_t err;
    a->bus = pb_bus_create_live(url, &err);
    if (!a->bus) { fprintf(stderr, PROG ": %s\n", err.msg); return 1; }
    a->status = pb_status_create(a->bus, PROG, STATUS_PERIOD_US);
    int fds[2] = { udp_socket(lidar_port, &err), -1 };
    if (fds[0] >= 0) fds[1] = udp_socket(imu_port, &err);
    if (fds[0] < 0 || fds[1] < 0) {
        fprintf(stderr, PROG ": %s\n", err.msg);
        pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_ERROR);
        pb_status_error(a->status, "%s", err.msg);
        pb_status_publish(a->status);
        if (fds[0] >= 0) close(fds[0]);
        pb_status_destroy(a->status);
        pb_bus_destroy(a->bus);
        return 1;
    }
    if (!quiet)
        fprintf(stderr, PROG ": lidar on UDP %d, IMU on UDP %d, publishing on %s\n", lidar_port, imu_port, pb_lcm_url(url));
    pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_OK);
    pb_status_publish(a->status);
    static uint8_t buf[65536];
    int64_t next_status = wall_utime() + STATUS_PERIOD_US;
    while (!pb_signal_stop_requested()) {
        struct pollfd p[2] = { { .fd = fds[0], .events = POLLIN }, { .fd = fds[1], .events = POLLIN } };
        int n = poll(p, 2, 50);
        if (n < 0 && errno != EINTR) { fprintf(stderr, PROG ": poll: %s\n", strerror(errno)); break; }
        for (int i = 0; i < 2 && n > 0; i++) {
            if (!(p[i].revents & POLLIN)) continue;
            for (;;) {   /* drain the socket */
                ssize_t got = recv(fds[i], buf, sizeof buf, MSG_DONTWAIT | MSG_TRUNC);
                if (got < 0) break;
                size_t len = (size_t)got;   /* MSG_TRUNC: the datagram's real size */
                if (len > sizeof buf) len = sizeof buf + 1;   /* wrong size either way: rejected by size */
                int64_t now = wall_utime();
                if (i == 0) ouster_driver_lidar_packet(a->drv, buf, len > sizeof buf ? sizeof buf : len, now);
                else ouster_driver_imu_packet(a->drv, buf, len > sizeof buf ? sizeof buf : len, now);
            }
        }
        int64_t now = wall_utime();
        ouster_driver_tick(a->drv, now);
        if (now >= next_status) {
            live_sync_status(a);
            pb_status_publish(a->status);
            next_status = now + STATUS_PERIOD_US;
        }
    }
    ouster_driver_flush(a->drv, wall_utime());
    live_sync_status(a);
    pb_status_finish(a->status, NULL);
    if (!quiet)
        fprintf(stderr, PROG ": %lld LIDAR_SCAN, %lld IMU published; %lld lidar and %lld IMU packets, %lld rejected\n",
                (long long)a->scans, (long long)a->imus, (long long)ouster_driver_counter(a->drv, "lidar_packets"),
                (long long)ouster_driver_counter(a->drv, "imu_packets"), (long long)rejects(a->drv));
    close(fds[0]);
    close(fds[1]);
    pb_status_destroy(a->status);
    pb_bus_destroy(a->bus);
    return 0;
}

int main(int argc, char **argv)
{
    const char *meta_path = NULL, *pcap_path = NULL, *out_path = NULL, *url = NULL;
    long lidar_port = -1, imu_port = -1;
    int quiet = 0;
    app_t a = { .lidar_channel = "LIDAR_SCAN", .imu_channel = "IMU" };
    ouster_config_t cfg;
    ouster_config_default(&cfg);
    static const char *const signals[] = { "auto", "on", "off" };   /* ouster_signal_mode_t */
    int signal = cfg.signal;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("metadata", &meta_path), PB_OPT_STRING("pcap", &pcap_path), PB_OPT_STRING("out", &out_path),
        PB_OPT_LONG("lidar-port", &lidar_port, 1, 65535), PB_OPT_LONG("imu-port", &imu_port, 1, 65535),
        PB_OPT_INT("return", &cfg.which_return, 1, 2), PB_OPT_CHOICE("signal", &signal, signals, 3),
        PB_OPT_FLAG("no-sensor-check", &cfg.check_sensor_id, 0), PB_OPT_STRING("lidar-channel", &a.lidar_channel),
        PB_OPT_STRING("imu-channel", &a.imu_channel), PB_OPT_STRING("lcm-url", &url), PB_OPT_FLAG("quiet", &quiet, 1),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse(PROG, opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    cfg.signal = (ouster_signal_mode_t)signal;
    if ((pcap_path != NULL) != (out_path != NULL)) { fprintf(stderr, PROG ": --pcap and --out go together\n"); return 2; }

    pb_err_t err;
    ouster_meta_t meta;
    if (ouster_meta_load(meta_path, &meta, &err) != 0) { fprintf(stderr, PROG ": %s\n", err.msg); return 1; }
    if (lidar_port < 0) lidar_port = meta.udp_port_lidar ? meta.udp_port_lidar : 7502;
    if (imu_port < 0) imu_port = meta.udp_port_imu ? meta.udp_port_imu : 7503;
    if (!quiet) {
        fprintf(stderr, PROG ": %s %s, %s, %d x %d (%d columns per packet, window %d..%d), %d Hz\n",
                meta.prod_line[0] ? meta.prod_line : "(no prod_line)", meta.fw_rev, ouster_profile_name(meta.profile),
                meta.rows, meta.cols_per_frame, meta.cols_per_packet, meta.column_window[0], meta.column_window[1],
                meta.frame_rate_hz);
        if (meta.defaults[0]) fprintf(stderr, PROG ": %s: defaults used for: %s\n", meta_path, meta.defaults);
    }
    a.drv = ouster_driver_create(&meta, &cfg, on_scan, on_imu, &a, &err);
    if (!a.drv) { fprintf(stderr, PROG ": %s: %s\n", meta_path, err.msg); return 1; }
    pb_signal_install();
    int rc = pcap_path ? run_pcap(&a, pcap_path, out_path, (int)lidar_port, (int)imu_port, quiet)
                       : run_live(&a, url, (int)lidar_port, (int)imu_port, quiet);
    ouster_driver_destroy(a.drv);
    free(a.enc);
    return rc;
}
