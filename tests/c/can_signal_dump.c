/* can_signal_dump DBC CANDUMP: every signal of every frame whose id the DBC knows and
 * whose length matches, one line each: "LINE ID NAME SIGNAL VALUE" (%.17g; raw for
 * multiplexed signals is printed only when their multiplexer selects them).
 * A test helper: tests/test_can.py compares it with cantools on the same frames. */
#include <stdio.h>
#include <stdlib.h>

#include "can/bench/can_inputs.h"

int main(int argc, char **argv)
{
    if (argc != 3) { fprintf(stderr, "usage: can_signal_dump DBC CANDUMP\n"); return 2; }
    can_dbc_t *dbc;
    can_frames_t in;
    if (can_inputs_load(argv[1], argv[2], &dbc, &in)) return 1;
    for (size_t k = 0; k < in.n; k++) {
        const pb_candump_frame_t *c = &in.frames[k];
        if (c->error || c->rtr) continue;
        const can_message_t *m = can_dbc_find(dbc, c->id, c->extended);
        if (!m || m->length != c->len) continue;
        const can_signal_t *mux = NULL;
        for (int i = 0; i < m->nsignals; i++) if (m->signals[i].is_multiplexer) mux = &m->signals[i];
        for (int i = 0; i < m->nsignals; i++) {
            const can_signal_t *s = &m->signals[i];
            if (s->multiplexed && (!mux || (uint64_t)can_signal_raw(mux, c->data) != s->mux_value)) continue;
            printf("%ld %u %s %s %.17g\n", in.lines[k], (unsigned)c->id, m->name, s->name, can_signal_value(s, c->data, c->len, NULL));
        }
    }
    free(in.frames);
    free(in.lines);
    can_dbc_destroy(dbc);
    return 0;
}
