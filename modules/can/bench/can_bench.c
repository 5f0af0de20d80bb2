/* can_bench DBC CANDUMP MODE PASSES: decodes the capture's frames PASSES times in
 * memory and prints "FRAMES SECONDS" (CPU time of the decode loop only).
 *   MODE signals: every signal of every bus-0 frame whose id and length the DBC knows
 *                 (what cantools' decode_message does per frame: the baseline's work)
 *   MODE speed:   can_speed_decode on every frame (the module's per-frame work)
 * Run by `make bench-can` (modules/can/bench/bench_can.py), which prints the table. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "can/bench/can_inputs.h"
#include "can/core/can_speed.h"
#include "pb_clock.h"

int main(int argc, char **argv)
{
    if (argc != 5) { fprintf(stderr, "usage: can_bench DBC CANDUMP signals|speed PASSES\n"); return 2; }
    can_dbc_t *dbc;
    can_frames_t in;
    if (can_inputs_load(argv[1], argv[2], &dbc, &in)) return 1;
    int passes = atoi(argv[4]), signals = !strcmp(argv[3], "signals");
    size_t n = in.n;
    can_rx_t *frames = malloc((n ? n : 1) * sizeof *frames);
    for (size_t i = 0; i < n; i++) {
        const pb_candump_frame_t *c = &in.frames[i];
        frames[i] = (can_rx_t){ .utime = c->utime, .bus = pb_candump_can_index(c->iface), .id = c->id,
                                .extended = c->extended, .rtr = c->rtr, .error = c->error, .fd = c->fd, .len = c->len };
        memcpy(frames[i].data, c->data, sizeof frames[i].data);
    }
    free(in.frames);
    free(in.lines);
    pb_err_t err;
    can_speed_config_t cfg;
    can_speed_config_default(&cfg);
    cfg.checksum = CAN_CHECKSUM_TOYOTA;
    can_speed_dec_t *dec = can_speed_create(dbc, &cfg, &err);
    if (!dec) { fprintf(stderr, "%s\n", err.msg); return 1; }
    volatile double sink = 0;
    long done = 0;
    double t0 = pb_clock_process_cpu_ms() * 1e-3;
    for (int p = 0; p < passes; p++) {
        for (size_t i = 0; i < n; i++) {
            const can_rx_t *fr = &frames[i];
            if (signals) {
                if (fr->bus != 0 || fr->error || fr->rtr) continue;
                const can_message_t *m = can_dbc_find(dbc, fr->id, fr->extended);
                if (!m || m->length != fr->len) continue;
                for (int k = 0; k < m->nsignals; k++) sink += can_signal_value(&m->signals[k], fr->data, fr->len, NULL);
                done++;
            } else {
                can_speed_t s;
                int back;
                if (can_speed_decode(dec, fr, &s, &back) == CAN_V_SPEED) sink += s.speed_mps;
                done++;
            }
        }
    }
    double dt = pb_clock_process_cpu_ms() * 1e-3 - t0;
    printf("%ld %.9f\n", done, dt);
    can_speed_destroy(dec);
    can_dbc_destroy(dbc);
    free(frames);
    return 0;
}
