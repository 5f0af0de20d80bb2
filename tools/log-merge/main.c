/* log-merge: merges LCM event logs into one, ordered by event timestamp.
 *
 * A module replayed with --replay IN --out OUT writes only what it publishes; to
 * feed the next module, merge IN and OUT. Ties keep the order of the inputs on the
 * command line, then each input's own order, so the output is deterministic.
 * Inputs are read strictly: a damaged input stops the merge naming file and byte,
 * and OUT keeps everything merged before it. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "pb_err.h"
#include "pb_log.h"
#include "pb_opt.h"
#include "pb_progress.h"

#define MAX_INPUTS 32
#define MAX_DROPS 32

typedef struct {
    const char *path;
    pb_log_t *log;
    pb_event_t ev;
    int has;        /* ev holds this input's next event */
} input_t;

static void usage(FILE *f)
{
    fprintf(f,
            "usage: log-merge --out OUT.lcm [--drop CHANNEL]... [--quiet] IN.lcm...\n"
            "Merges event logs into one, ordered by timestamp (ties: inputs in command-line\n"
            "order). Typical use: replay a module, then merge its output with its input to\n"
            "feed the next module:\n"
            "  can --replay drive.lcm --out speed.lcm && log-merge --out all.lcm drive.lcm speed.lcm\n"
            "  --out OUT.lcm     merged log (must not be one of the inputs)\n"
            "  --drop CHANNEL    leave out every event on CHANNEL (repeatable, exact name)\n"
            "  --quiet           no progress bar\n"
            "  -h, --help        this text\n"
            "Exit status: 0 merged; 1 an input is missing or damaged (OUT keeps what was merged\n"
            "before it; the message names the file and byte); 2 bad options.\n");
}

static int advance(input_t *in, pb_err_t *err)
{
    int rc = pb_log_next(in->log, &in->ev, err);
    in->has = rc == 1;
    return rc < 0 ? -1 : 0;
}

typedef struct { const char *names[MAX_DROPS]; int n; } drops_t;

static int add_drop(const char *prog, const char *arg, void *var)
{
    drops_t *d = var;
    if (d->n == MAX_DROPS) { fprintf(stderr, "%s: at most %d --drop\n", prog, MAX_DROPS); return -1; }
    d->names[d->n++] = arg;
    return 0;
}

int main(int argc, char **argv)
{
    const char *out_path = NULL;
    drops_t drops = { .n = 0 };
    int quiet = 0;
    const pb_opt_t opts[] = {
        PB_OPT_ENTRY("out", 'o', PB_OPT_K_STRING, &out_path, 0, 0, 0, 0, NULL),
        PB_OPT_ENTRY("drop", 'd', PB_OPT_K_CALL, &drops, 0, 0, 0, 0, add_drop),
        PB_OPT_ENTRY("quiet", 'q', PB_OPT_K_FLAG, &quiet, 1, 0, 0, 0, NULL), PB_OPT_END,
    };
    int parsed = pb_opt_parse("log-merge", opts, usage, PB_OPT_ARGS, argc, argv);
    if (parsed >= 0) return parsed;
    int nin = argc - optind;
    if (!out_path || nin < 1) {
        fprintf(stderr, "log-merge: need --out and at least one input log\n");
        usage(stderr);
        return 2;
    }
    if (nin > MAX_INPUTS) { fprintf(stderr, "log-merge: at most %d inputs\n", MAX_INPUTS); return 2; }
    for (int i = 0; i < nin; i++)
        if (strcmp(argv[optind + i], out_path) == 0) {
            fprintf(stderr, "log-merge: --out %s is also an input\n", out_path);
            return 2;
        }

    pb_err_t err = { "" };
    input_t in[MAX_INPUTS] = { 0 };
    int64_t total = 0, done = 0;
    pb_log_t *out = NULL;
    int status = 1;
    for (int i = 0; i < nin; i++) {
        in[i].path = argv[optind + i];
        if (!(in[i].log = pb_log_open_read(in[i].path, &err))) goto done;
        total += pb_log_size(in[i].log);
    }
    if (!(out = pb_log_open_write(out_path, &err))) goto done;
    for (int i = 0; i < nin; i++)
        if (advance(&in[i], &err) < 0) goto done;

    pb_progress_t prog;
    pb_progress_start(&prog, "merge", total, quiet);
    int64_t written = 0, dropped = 0;
    for (;;) {
        int best = -1;      /* earliest event; strict < keeps the first input on ties */
        for (int i = 0; i < nin; i++)
            if (in[i].has && (best < 0 || in[i].ev.timestamp < in[best].ev.timestamp)) best = i;
        if (best < 0) break;
        const pb_event_t *ev = &in[best].ev;
        int drop = 0;
        for (int d = 0; d < drops.n; d++) drop |= strcmp(ev->channel, drops.names[d]) == 0;
        if (drop) dropped++;
        else if (pb_log_write(out, ev->timestamp, ev->channel, ev->data, ev->datalen, &err) < 0) goto done;
        else written++;
        if (advance(&in[best], &err) < 0) goto done;
        if ((++done & 1023) == 0) {
            int64_t pos = 0;
            for (int i = 0; i < nin; i++) pos += pb_log_position(in[i].log);
            pb_progress_update(&prog, pos);
        }
    }
    pb_progress_update(&prog, total);
    pb_progress_finish(&prog);
    if (!quiet) fprintf(stderr, "log-merge: %lld events written, %lld dropped\n", (long long)written, (long long)dropped);
    status = 0;
done:
    for (int i = 0; i < nin; i++) pb_log_close(in[i].log, NULL);
    if (pb_log_close(out, status ? NULL : &err) < 0) status = 1;
    if (status) fprintf(stderr, "log-merge: %s\n", err.msg);
    return status;
}
