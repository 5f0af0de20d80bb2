/* libFuzzer target: DBC text, arbitrary bytes. A database it returns must be
 * self-consistent: every signal inside its message, lookups find every message,
 * and decoding every signal of every message (and the speed decoder, when the
 * text defines its messages) stays inside the frame.
 * fuzz-sources: modules/can/core/can_dbc.c modules/can/core/can_speed.c common/pb_err.c */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "can/core/can_dbc.h"
#include "can/core/can_speed.h"
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    pb_err_t err;
    can_dbc_t *db = can_dbc_parse((const char *)data, size, &err);
    if (!db) {
        if (!memchr(err.msg, ':', sizeof err.msg)) abort();    /* "LINE:COL: what" */
        return 0;
    }
    uint8_t *frame = malloc(64);                   /* exact size: ASan sees any overread */
    for (int i = 0; i < 64; i++) frame[i] = (uint8_t)(0xA5 ^ (i * 37));
    for (int i = 0; i < can_dbc_message_count(db); i++) {
        const can_message_t *m = can_dbc_message_at(db, i);
        if (m->length > 64 || can_dbc_find(db, m->id, m->extended) != m) abort();
        uint8_t *exact = fuzz_copy(frame, m->length);
        for (int k = 0; k < m->nsignals; k++) {
            const can_signal_t *s = &m->signals[k];
            if (s->length < 1 || s->length > 64 || s->last_byte >= m->length) abort();
            int ok;
            (void)can_signal_value(s, exact, m->length, &ok);
            if (!ok) abort();
        }
        free(exact);
    }
    can_speed_config_t cfg;
    can_speed_config_default(&cfg);
    cfg.checksum = CAN_CHECKSUM_TOYOTA;
    can_speed_dec_t *dec = can_speed_create(db, &cfg, &err);
    if (dec) {
        for (int i = 0; i < can_dbc_message_count(db); i++) {
            const can_message_t *m = can_dbc_message_at(db, i);
            can_rx_t f;
            memset(&f, 0, sizeof f);
            f.id = m->id;
            f.extended = m->extended;
            f.len = m->length;
            memcpy(f.data, frame, m->length);
            can_speed_t out;
            int back;
            can_verdict_t v = can_speed_decode(dec, &f, &out, &back);
            if ((unsigned)v >= CAN_V_COUNT) abort();
        }
        can_speed_destroy(dec);
    }
    free(frame);
    can_dbc_destroy(db);
    return 0;
}
