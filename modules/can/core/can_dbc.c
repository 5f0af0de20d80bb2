/* DBC reader: BO_, SG_ and VAL_ lines strictly, everything else skipped (see can_dbc.h). */
#include "can_dbc.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* One entry of a signal's value table (VAL_): raw value -> label. */
typedef struct {
    uint32_t dbc_id;        /* the id as written (bit 31: extended) */
    char signal[CAN_DBC_NAME_MAX];
    int64_t raw;
    char label[CAN_DBC_NAME_MAX];
} can_value_t;

struct can_dbc {
    can_message_t *msgs;
    int nmsgs, cap;
    can_value_t *vals;
    int nvals, vcap;
};

/* A cursor over one line: [p, end). */
typedef struct {
    const char *line, *p, *end;
    long lineno;
    pb_err_t *err;
} cur_t;

static int fail(cur_t *c, const char *what)
{
    return pb_err_set(c->err, "%ld:%ld: %s", c->lineno, (long)(c->p - c->line) + 1, what);
}

static void skip_ws(cur_t *c)
{
    while (c->p < c->end && (*c->p == ' ' || *c->p == '\t')) c->p++;
}

static int is_ident_char(char ch)
{
    return (ch >= 'A' && ch <= 'Z') || (ch >= 'a' && ch <= 'z') || (ch >= '0' && ch <= '9') || ch == '_';
}

static int expect(cur_t *c, char ch, const char *what)
{
    skip_ws(c);
    if (c->p >= c->end || *c->p != ch) return fail(c, what);
    c->p++;
    return 0;
}

static int read_ident(cur_t *c, char *out, size_t cap, const char *what)
{
    skip_ws(c);
    const char *s = c->p;
    while (c->p < c->end && is_ident_char(*c->p)) c->p++;
    size_t n = (size_t)(c->p - s);
    if (n == 0) { c->p = s; return fail(c, what); }
    if (n >= cap) { c->p = s; return fail(c, "name too long"); }
    memcpy(out, s, n);
    out[n] = 0;
    return 0;
}

static int read_uint(cur_t *c, uint64_t max, uint64_t *out, const char *what)
{
    skip_ws(c);
    const char *s = c->p;
    uint64_t v = 0;
    while (c->p < c->end && *c->p >= '0' && *c->p <= '9') {
        v = v * 10 + (uint64_t)(*c->p - '0');
        if (v > max) { c->p = s; return fail(c, what); }
        c->p++;
    }
    if (c->p == s) return fail(c, what);
    *out = v;
    return 0;
}

/* A decimal number as strtod reads it, copied out first: the line has no terminator. */
static int read_number(cur_t *c, double *out, const char *what)
{
    skip_ws(c);
    const char *s = c->p;
    char buf[64];
    size_t n = 0;
    while (c->p < c->end && n < sizeof buf - 1 &&
           ((*c->p >= '0' && *c->p <= '9') || *c->p == '.' || *c->p == '-' || *c->p == '+' ||
            *c->p == 'e' || *c->p == 'E'))
        buf[n++] = *c->p++;
    buf[n] = 0;
    char *e;
    errno = 0;
    double v = n ? strtod(buf, &e) : 0;
    if (n == 0 || *e != 0 || !isfinite(v)) { c->p = s; return fail(c, what); }
    *out = v;
    return 0;
}

static int read_quoted(cur_t *c, char *out, size_t cap, const char *what)
{
    skip_ws(c);
    if (c->p >= c->end || *c->p != '"') return fail(c, what);
    const char *s = ++c->p;
    while (c->p < c->end && *c->p != '"') c->p++;
    if (c->p >= c->end) { c->p = s - 1; return fail(c, "unterminated string"); }
    size_t n = (size_t)(c->p - s);
    if (n >= cap) { c->p = s; return fail(c, "string too long"); }
    memcpy(out, s, n);
    out[n] = 0;
    c->p++;
    return 0;
}

/* A value-table label: quoted, any length (descriptions are long); kept up to cap - 1
 * characters, which is more than any label a decoder looks up. */
static int read_label(cur_t *c, char *out, size_t cap)
{
    skip_ws(c);
    if (c->p >= c->end || *c->p != '"') return fail(c, "quoted label expected");
    const char *s = ++c->p;
    while (c->p < c->end && *c->p != '"') c->p++;
    if (c->p >= c->end) { c->p = s - 1; return fail(c, "unterminated string"); }
    size_t n = (size_t)(c->p - s) < cap - 1 ? (size_t)(c->p - s) : cap - 1;
    memcpy(out, s, n);
    out[n] = 0;
    c->p++;
    return 0;
}

/* Receivers / sender list: identifiers separated by commas or blanks, to the end of the line. */
static int read_node_list(cur_t *c)
{
    for (;;) {
        skip_ws(c);
        if (c->p >= c->end) return 0;
        if (*c->p == ',') { c->p++; continue; }
        if (!is_ident_char(*c->p)) return fail(c, "unexpected character in node list");
        while (c->p < c->end && is_ident_char(*c->p)) c->p++;
    }
}

/* Where a signal's bits end, checked against the message length. */
static int signal_last_byte(const can_signal_t *s)
{
    if (!s->big_endian) return (s->start + s->length - 1) / 8;
    int bit = s->start;
    for (int k = 1; k < s->length; k++) bit = (bit % 8 == 0) ? bit + 15 : bit - 1;
    return bit / 8;
}

static int parse_bo(cur_t *c, can_dbc_t *db, int *skip_signals)
{
    uint64_t id, len;
    char name[CAN_DBC_NAME_MAX];
    if (read_uint(c, 0xFFFFFFFFu, &id, "message id: expected a decimal number") ||
        read_ident(c, name, sizeof name, "message name expected") ||
        expect(c, ':', "':' expected after the message name") ||
        read_uint(c, 64, &len, "message length: expected 0-64") ||
        read_node_list(c))
        return -1;
    int extended = (id & 0x80000000u) != 0;
    uint32_t arb = (uint32_t)(id & 0x7FFFFFFFu);
    /* VECTOR__INDEPENDENT_SIG_MSG (0xC0000000) holds signals of no message: not a frame. */
    if (arb > 0x1FFFFFFFu || (!extended && arb > 0x7FF)) {
        if (strcmp(name, "VECTOR__INDEPENDENT_SIG_MSG") == 0) { *skip_signals = 1; return 0; }
        c->p = c->line;
        return fail(c, extended ? "message id beyond 29 bits" : "standard message id beyond 11 bits");
    }
    for (int i = 0; i < db->nmsgs; i++)
        if (db->msgs[i].id == arb && db->msgs[i].extended == extended) {
            c->p = c->line;
            return fail(c, "duplicate message id");
        }
    if (db->nmsgs == db->cap) {
        int cap = db->cap ? db->cap * 2 : 64;
        can_message_t *m = realloc(db->msgs, (size_t)cap * sizeof *m);
        if (!m) return fail(c, "out of memory");
        db->msgs = m;
        db->cap = cap;
    }
    can_message_t *m = &db->msgs[db->nmsgs++];
    memset(m, 0, sizeof *m);
    m->id = arb;
    m->extended = (uint8_t)extended;
    m->length = (uint8_t)len;
    memcpy(m->name, name, sizeof name);
    *skip_signals = 0;
    return 0;
}

static int parse_sg(cur_t *c, can_message_t *m)
{
    can_signal_t s;
    memset(&s, 0, sizeof s);
    if (read_ident(c, s.name, sizeof s.name, "signal name expected")) return -1;
    skip_ws(c);
    if (c->p < c->end && *c->p == 'M') {
        s.is_multiplexer = 1;
        c->p++;
    } else if (c->p < c->end && *c->p == 'm') {
        c->p++;
        uint64_t v;
        if (read_uint(c, 0xFFFFFFFFu, &v, "multiplex value expected after 'm'")) return -1;
        s.multiplexed = 1;
        s.mux_value = (uint32_t)v;
        if (c->p < c->end && *c->p == 'M') { s.is_multiplexer = 1; c->p++; }
    }
    uint64_t start, length;
    if (expect(c, ':', "':' expected after the signal name") ||
        read_uint(c, 511, &start, "start bit: expected 0-511") ||
        expect(c, '|', "'|' expected after the start bit") ||
        read_uint(c, 64, &length, "bit length: expected 1-64") ||
        expect(c, '@', "'@' expected after the bit length"))
        return -1;
    if (length == 0) { c->p--; return fail(c, "bit length: expected 1-64"); }
    if (c->p >= c->end || (*c->p != '0' && *c->p != '1')) return fail(c, "byte order: expected 0 (Motorola) or 1 (Intel)");
    s.big_endian = *c->p++ == '0';
    if (c->p >= c->end || (*c->p != '+' && *c->p != '-')) return fail(c, "sign: expected '+' or '-'");
    s.is_signed = *c->p++ == '-';
    s.start = (uint16_t)start;
    s.length = (uint8_t)length;
    if (expect(c, '(', "'(' expected before the factor") || read_number(c, &s.factor, "factor: expected a number") ||
        expect(c, ',', "',' expected after the factor") || read_number(c, &s.offset, "offset: expected a number") ||
        expect(c, ')', "')' expected after the offset") ||
        expect(c, '[', "'[' expected before the minimum") || read_number(c, &s.minimum, "minimum: expected a number") ||
        expect(c, '|', "'|' expected after the minimum") || read_number(c, &s.maximum, "maximum: expected a number") ||
        expect(c, ']', "']' expected after the maximum") ||
        read_quoted(c, s.unit, sizeof s.unit, "quoted unit expected") || read_node_list(c))
        return -1;
    int last = signal_last_byte(&s);
    if (last >= m->length) {
        c->p = c->line;
        char what[256];
        snprintf(what, sizeof what, "signal %s (bits %u|%u@%d) does not fit in %s's %u bytes",
                 s.name, s.start, s.length, s.big_endian ? 0 : 1, m->name, m->length);
        return fail(c, what);
    }
    s.last_byte = (uint8_t)last;
    for (int i = 0; i < m->nsignals; i++)
        if (strcmp(m->signals[i].name, s.name) == 0) { c->p = c->line; return fail(c, "duplicate signal name in message"); }
    can_signal_t *arr = realloc(m->signals, (size_t)(m->nsignals + 1) * sizeof *arr);
    if (!arr) return fail(c, "out of memory");
    m->signals = arr;
    m->signals[m->nsignals++] = s;
    return 0;
}

/* VAL_ <id> <signal> (<raw> "<label>")* ; -- a signal's value table. Environment
 * variable tables (VAL_ <name> ...) have no id and are skipped by the caller. */
static int parse_val(cur_t *c, can_dbc_t *db)
{
    uint64_t id;
    char sig[CAN_DBC_NAME_MAX];
    if (read_uint(c, 0xFFFFFFFFu, &id, "message id expected")) return -1;
    if (read_ident(c, sig, sizeof sig, "signal name expected")) return -1;
    for (;;) {
        skip_ws(c);
        if (c->p < c->end && *c->p == ';') return 0;
        if (c->p >= c->end) return fail(c, "';' expected at the end of the value table");
        int neg = *c->p == '-';
        if (neg) c->p++;
        uint64_t raw;
        if (read_uint(c, INT64_MAX, &raw, "raw value expected")) return -1;
        can_value_t v = { (uint32_t)id, "", neg ? -(int64_t)raw : (int64_t)raw, "" };
        memcpy(v.signal, sig, sizeof sig);
        if (read_label(c, v.label, sizeof v.label)) return -1;
        if (db->nvals == db->vcap) {
            int cap = db->vcap ? 2 * db->vcap : 64;
            can_value_t *m = realloc(db->vals, (size_t)cap * sizeof *m);
            if (!m) return fail(c, "out of memory");
            db->vals = m;
            db->vcap = cap;
        }
        db->vals[db->nvals++] = v;
    }
}

static int cmp_msg(const void *a, const void *b)
{
    const can_message_t *x = a, *y = b;
    if (x->extended != y->extended) return x->extended < y->extended ? -1 : 1;
    return x->id < y->id ? -1 : x->id > y->id;
}

/* Keyword at the cursor followed by a blank (so "BO_TX_BU_" is not "BO_"). */
static int keyword(const cur_t *c, const char *kw)
{
    size_t n = strlen(kw);
    return (size_t)(c->end - c->p) > n && memcmp(c->p, kw, n) == 0 && (c->p[n] == ' ' || c->p[n] == '\t');
}

can_dbc_t *can_dbc_parse(const char *text, size_t len, pb_err_t *err)
{
    can_dbc_t *db = calloc(1, sizeof *db);
    if (!db) { pb_err_set(err, "out of memory"); return NULL; }
    const char *p = text, *end = text + len;
    long lineno = 0;
    int in_string = 0, skip_signals = 0;
    can_message_t *cur_msg = NULL;
    while (p < end) {
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        const char *next = eol ? eol + 1 : end;
        if (!eol) eol = end;
        if (eol > p && eol[-1] == '\r') eol--;
        lineno++;
        cur_t c = { p, p, eol, lineno, err };
        size_t linelen = eol > p ? (size_t)(eol - p) : 0;
        const char *nul = memchr(p, 0, linelen);
        if (nul) {
            c.p = nul;
            fail(&c, "NUL byte");
            goto bad;
        }
        skip_ws(&c);
        int parsed = 0;
        if (!in_string && keyword(&c, "BO_")) {
            c.p += 3;
            if (parse_bo(&c, db, &skip_signals)) goto bad;
            cur_msg = skip_signals ? NULL : &db->msgs[db->nmsgs - 1];
            parsed = 1;
        } else if (!in_string && keyword(&c, "SG_")) {
            c.p += 3;
            if (!cur_msg && !skip_signals) { fail(&c, "signal outside a message"); goto bad; }
            if (cur_msg && parse_sg(&c, cur_msg)) goto bad;
            parsed = 1;
        } else if (!in_string && keyword(&c, "VAL_")) {
            c.p += 4;
            skip_ws(&c);
            cur_msg = NULL;
            skip_signals = 0;
            if (c.p < c.end && *c.p >= '0' && *c.p <= '9') {
                if (parse_val(&c, db)) goto bad;
                parsed = 1;
            }
        } else if (!in_string && c.p < c.end && is_ident_char(*c.p)) {
            cur_msg = NULL;     /* any other section ends the message's signal list */
            skip_signals = 0;
        }
        if (!parsed) {
            /* Strings (CM_ comments, attribute values) may span lines. */
            for (const char *q = c.line; q < eol; q++) {
                if (in_string && *q == '\\' && q + 1 < eol) q++;
                else if (*q == '"') in_string = !in_string;
            }
        }
        p = next;
    }
    if (db->nmsgs) qsort(db->msgs, (size_t)db->nmsgs, sizeof *db->msgs, cmp_msg);
    return db;
bad:
    can_dbc_destroy(db);
    return NULL;
}

can_dbc_t *can_dbc_load(const char *path, pb_err_t *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) { pb_err_set(err, "%s: %s", path, strerror(errno)); return NULL; }
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap);
    size_t got;
    while (buf && (got = fread(buf + n, 1, cap - n, f)) > 0) {
        n += got;
        if (n == cap) { char *b = realloc(buf, cap *= 2); if (!b) { free(buf); buf = NULL; } else buf = b; }
    }
    int rerr = ferror(f);
    fclose(f);
    if (!buf || rerr) { free(buf); pb_err_set(err, "%s: %s", path, buf ? "read error" : "out of memory"); return NULL; }
    can_dbc_t *db = can_dbc_parse(buf, n, err);
    free(buf);
    if (!db && err) {
        char msg[sizeof err->msg];
        memcpy(msg, err->msg, sizeof msg);
        pb_err_set(err, "%s:%s", path, msg);    /* "FILE:LINE:COL: what" */
    }
    return db;
}

void can_dbc_destroy(can_dbc_t *dbc)
{
    if (!dbc) return;
    for (int i = 0; i < dbc->nmsgs; i++) free(dbc->msgs[i].signals);
    free(dbc->msgs);
    free(dbc->vals);
    free(dbc);
}

int can_dbc_message_count(const can_dbc_t *dbc) { return dbc->nmsgs; }

const can_message_t *can_dbc_message_at(const can_dbc_t *dbc, int index)
{
    return index >= 0 && index < dbc->nmsgs ? &dbc->msgs[index] : NULL;
}

const can_message_t *can_dbc_find(const can_dbc_t *dbc, uint32_t id, int extended)
{
    if (!dbc->nmsgs) return NULL;
    can_message_t key;
    key.id = id;
    key.extended = extended ? 1 : 0;
    return bsearch(&key, dbc->msgs, (size_t)dbc->nmsgs, sizeof *dbc->msgs, cmp_msg);
}

const can_message_t *can_dbc_find_name(const can_dbc_t *dbc, const char *name)
{
    for (int i = 0; i < dbc->nmsgs; i++)
        if (strcmp(dbc->msgs[i].name, name) == 0) return &dbc->msgs[i];
    return NULL;
}

const can_signal_t *can_message_signal(const can_message_t *msg, const char *name)
{
    for (int i = 0; i < msg->nsignals; i++)
        if (strcmp(msg->signals[i].name, name) == 0) return &msg->signals[i];
    return NULL;
}

int64_t can_signal_raw(const can_signal_t *sig, const uint8_t *data)
{
    uint64_t v = 0;
    int n = sig->length;
    if (sig->big_endian) {
        /* MSB first, walking down within a byte and on to the next byte's bit 7. */
        int bit = sig->start;
        for (int k = 0; k < n; k++) {
            v = (v << 1) | ((data[bit >> 3] >> (bit & 7)) & 1u);
            bit = (bit & 7) == 0 ? bit + 15 : bit - 1;
        }
    } else {
        for (int k = 0; k < n; k++) {
            int bit = sig->start + k;
            v |= (uint64_t)((data[bit >> 3] >> (bit & 7)) & 1u) << k;
        }
    }
    if (sig->is_signed && n < 64 && (v >> (n - 1)) & 1u) v |= ~0ull << n;
    return (int64_t)v;
}

double can_signal_value(const can_signal_t *sig, const uint8_t *data, int len, int *ok)
{
    if (len <= sig->last_byte) {
        if (ok) *ok = 0;
        return 0;
    }
    if (ok) *ok = 1;
    int64_t raw = can_signal_raw(sig, data);
    double r = sig->is_signed ? (double)raw : (double)(uint64_t)raw;
    return r * sig->factor + sig->offset;
}

int can_dbc_value_raw(const can_dbc_t *dbc, const can_message_t *msg, const char *signal, const char *label,
                      int64_t *raw)
{
    uint32_t dbc_id = msg->id | (msg->extended ? 0x80000000u : 0);
    for (int i = 0; i < dbc->nvals; i++) {
        const can_value_t *v = &dbc->vals[i];
        if (v->dbc_id == dbc_id && strcmp(v->signal, signal) == 0 && strcmp(v->label, label) == 0) {
            *raw = v->raw;
            return 0;
        }
    }
    return -1;
}
