/* log-summary: what a drive log (or the live bus) holds, and how the vehicle moved.
 *   log-summary --replay IN.lcm --out OUT.lcm     a log, as fast as the CPU allows
 *   log-summary [--lcm-url URL]                   the live bus, summary on Ctrl-C
 * Publishes its STATUS heartbeat (to OUT in replay). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pb_bus.h"
#include "pb_opt.h"
#include "pb_signal.h"
#include "pb_status.h"
#include "portobello_can_frame_t.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_pose_t.h"
#include "portobello_status_t.h"
#include "summary.h"

typedef struct {
    summary_t sum;
    pb_status_t *status;
    const char *pose_channel;
} app_t;

static void usage(FILE *f)
{
    fprintf(f,
            "usage: log-summary [--replay IN.lcm --out OUT.lcm] [--lcm-url URL] [--pose-channel CH]\n"
            "Summarises the messages of a log (or of the live bus until Ctrl-C): per channel the\n"
            "count, rate, size and time span; the distance, speeds and stops of the vehicle from\n"
            "the pose channel (default GROUND_TRUTH); LiDAR returns; CAN ids.\n"
            "  --replay IN.lcm   read a log, time taken from the log\n"
            "  --out OUT.lcm     where the replay writes what the tool publishes (STATUS)\n"
            "  --lcm-url URL     live bus (default $LCM_DEFAULT_URL or %s)\n"
            "  --pose-channel CH pose channel to summarise (default GROUND_TRUTH)\n"
            "  -h, --help        this text\n", PB_DEFAULT_LCM_URL);
}

/* Decodes what the summary needs; a message that does not decode is counted, not fatal. */
static void on_message(const pb_msg_t *m, void *user)
{
    app_t *a = user;
    int64_t utime = m->recv_utime;
    if (strcmp(m->channel, "LIDAR_SCAN") == 0) {
        portobello_lidar_scan_t s;
        if (portobello_lidar_scan_t_decode(m->data, 0, m->len, &s) < 0) goto bad;
        int32_t valid = s.npoints;
        for (int i = 0; i < s.npixels; i++) valid += s.range_mm[i] > 0;
        summary_scan(&a->sum, valid, s.npixels ? s.npixels : s.npoints);
        utime = s.utime;
        portobello_lidar_scan_t_decode_cleanup(&s);
    } else if (strcmp(m->channel, a->pose_channel) == 0) {
        portobello_pose_t p;
        if (portobello_pose_t_decode(m->data, 0, m->len, &p) < 0) goto bad;
        summary_pose(&a->sum, p.utime, p.position, p.velocity);
        utime = p.utime;
    } else if (strcmp(m->channel, "CAN_FRAME") == 0) {
        portobello_can_frame_t c;
        if (portobello_can_frame_t_decode(m->data, 0, m->len, &c) < 0) goto bad;
        summary_can(&a->sum, c.id);
        utime = c.utime;
        portobello_can_frame_t_decode_cleanup(&c);
    } else if (m->len >= 16) {
        /* Every portobello type starts with its 8-byte hash and then int64 utime. */
        utime = 0;
        for (int i = 8; i < 16; i++) utime = (utime << 8) | m->data[i];
        if (utime < m->recv_utime - 86400000000LL || utime > m->recv_utime + 86400000000LL)
            utime = m->recv_utime;   /* not one of ours: fall back to the receive time */
    }
    summary_message(&a->sum, m->channel, utime, m->len);
    pb_status_input_time(a->status, m->channel, utime);
    return;
bad:
    pb_status_undecodable(a->status, "undecodable", m);
    summary_message(&a->sum, m->channel, utime, m->len);
}

int main(int argc, char **argv)
{
    const char *url = NULL, *in = NULL, *out = NULL;
    app_t a = { .pose_channel = "GROUND_TRUTH" };
    const pb_opt_t opts[] = {
        PB_OPT_STRING("replay", &in), PB_OPT_STRING("out", &out), PB_OPT_STRING("lcm-url", &url),
        PB_OPT_STRING("pose-channel", &a.pose_channel), PB_OPT_END,
    };
    int parsed = pb_opt_parse("log-summary", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    if ((in != NULL) != (out != NULL)) { fprintf(stderr, "log-summary: --replay and --out go together\n"); return 2; }

    pb_err_t err;
    pb_bus_t *bus = in ? pb_bus_create_replay(in, out, &err) : pb_bus_create_live(url, &err);
    if (!bus) { fprintf(stderr, "log-summary: %s\n", err.msg); return 1; }
    pb_signal_install();
    summary_init(&a.sum);
    a.status = pb_status_create(bus, "log-summary", 1000000);
    pb_status_set_state(a.status, PORTOBELLO_STATUS_T_STATE_OK);
    pb_bus_subscribe(bus, ".*", on_message, &a);
    if (!in) fprintf(stderr, "log-summary: listening on %s; Ctrl-C prints the summary\n", pb_lcm_url(url));

    int rc = pb_bus_run(bus, &err);
    pb_status_finish(a.status, rc ? err.msg : NULL);
    if (rc != 0)
        fprintf(stderr, "log-summary: stopped after %lld events; the summary below covers them\n",
                (long long)pb_bus_events_read(bus));
    summary_print(&a.sum, stdout);
    pb_status_destroy(a.status);
    pb_bus_destroy(bus);
    return rc == 0 ? 0 : 1;
}
