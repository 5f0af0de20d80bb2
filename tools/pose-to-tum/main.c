/* pose-to-tum: one pose channel of an LCM log as a TUM trajectory file, for evo.
 *   pose-to-tum --log IN.lcm --channel POSE --out FILE.tum [--status tracking|any] */
#include <stdio.h>
#include <string.h>

#include "pb_log.h"
#include "pb_opt.h"
#include "tum.h"

static void usage(FILE *f)
{
    fprintf(f,
            "usage: pose-to-tum --log IN.lcm --out FILE.tum [--channel CH] [--tracking-only]\n"
            "Writes the pose_t messages of one channel of an LCM log as a TUM trajectory\n"
            "(\"t x y z qx qy qz qw\", t in seconds = the pose's utime), in log order, for\n"
            "evo (evo_ape tum ground_truth.tum FILE.tum).\n"
            "  --log IN.lcm       the log\n"
            "  --channel CH       pose channel (default POSE; GROUND_TRUTH, POSE_PREDICTED, ...)\n"
            "  --out FILE.tum     output file ('-' = stdout)\n"
            "  --tracking-only    keep only poses with status TRACKING\n"
            "  -h, --help         this text\n"
            "Exit status 1 if the log is damaged (the poses before the damage are written) or a\n"
            "message does not decode; the count of poses written is printed to stderr.\n");
}

int main(int argc, char **argv)
{
    const char *in = NULL, *out = NULL, *channel = "POSE";
    int tracking_only = 0;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("log", &in), PB_OPT_STRING("channel", &channel), PB_OPT_REQUIRED("out", &out),
        PB_OPT_FLAG("tracking-only", &tracking_only, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse("pose-to-tum", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;

    pb_err_t err;
    pb_log_t *log = pb_log_open_read(in, &err);
    if (!log) { fprintf(stderr, "pose-to-tum: %s\n", err.msg); return 1; }
    FILE *f = strcmp(out, "-") == 0 ? stdout : fopen(out, "w");
    if (!f) { fprintf(stderr, "pose-to-tum: %s: cannot write\n", out); pb_log_close(log, NULL); return 1; }
    pb_event_t ev;
    long long written = 0, skipped = 0, bad = 0;
    int rc = 0, r;
    while ((r = pb_log_next(log, &ev, &err)) == 1) {
        if (strcmp(ev.channel, channel) != 0) continue;
        portobello_pose_t p;
        if (portobello_pose_t_decode(ev.data, 0, ev.datalen, &p) < 0) {
            fprintf(stderr, "pose-to-tum: %s: byte %lld: %s message does not decode as pose_t\n", in,
                    (long long)ev.offset, channel);
            bad++;
            continue;
        }
        if (tracking_only && p.status != PORTOBELLO_POSE_T_STATUS_TRACKING) { skipped++; continue; }
        char line[256];
        if (tum_format(&p, line, sizeof line) < 0) { skipped++; continue; }
        fputs(line, f);
        written++;
    }
    if (r < 0) { fprintf(stderr, "pose-to-tum: %s\n", err.msg); rc = 1; }
    if (bad) rc = 1;
    if (f != stdout && fclose(f) != 0) { fprintf(stderr, "pose-to-tum: %s: write failed\n", out); rc = 1; }
    pb_log_close(log, NULL);
    fprintf(stderr, "pose-to-tum: %lld poses of %s written to %s (%lld skipped, %lld undecodable)\n", written, channel,
            out, skipped, bad);
    if (written == 0 && rc == 0) fprintf(stderr, "pose-to-tum: warning: no %s poses in %s\n", channel, in);
    return rc;
}
