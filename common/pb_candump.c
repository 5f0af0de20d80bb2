/* pb_candump: see pb_candump.h. Every read is bounds-checked against len. */
#include "pb_candump.h"

#include <stdio.h>
#include <string.h>

static int is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }

static int hexval(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static int fd_len_valid(int n)
{
    return n <= 8 || n == 12 || n == 16 || n == 20 || n == 24 || n == 32 || n == 48 || n == 64;
}

/* Reads hex byte pairs (optionally '.'-separated) from s[*i] up to whitespace,
 * '_' or the end. Returns 0 or an error code with *i at the offending byte. */
static int parse_data(const char *s, size_t len, size_t *i, int max, pb_candump_frame_t *f)
{
    int n = 0;
    while (*i < len && !is_space(s[*i]) && s[*i] != '_') {
        if (s[*i] == '.') {             /* separator between bytes only */
            if (n == 0 || *i + 1 >= len || hexval(s[*i + 1]) < 0) return PB_CANDUMP_E_DATA;
            (*i)++;
            continue;
        }
        int hi = hexval(s[*i]);
        if (hi < 0) return PB_CANDUMP_E_DATA;
        if (*i + 1 >= len) return PB_CANDUMP_E_DATA;    /* odd digit count */
        int lo = hexval(s[*i + 1]);
        if (lo < 0) { (*i)++; return PB_CANDUMP_E_DATA; }
        if (n >= max) return PB_CANDUMP_E_LEN;
        f->data[n++] = (uint8_t)(hi << 4 | lo);
        *i += 2;
    }
    f->len = (uint8_t)n;
    return 0;
}

int pb_candump_parse(const char *s, size_t len, pb_candump_frame_t *f, size_t *col)
{
    size_t i = 0;
    int rc;
    if (!s) len = 0;
    memset(f, 0, sizeof *f);

    while (i < len && is_space(s[i])) i++;
    if (i == len) return PB_CANDUMP_BLANK;

    /* "(SECONDS.USEC)": integer arithmetic so the time is exact. */
    rc = PB_CANDUMP_E_TIME;
    if (s[i] != '(') goto fail;
    i++;
    int64_t sec = 0;
    int nd = 0;
    while (i < len && s[i] >= '0' && s[i] <= '9') {
        if (++nd > 12) goto fail;           /* keeps sec * 1e6 far from overflow */
        sec = sec * 10 + (s[i] - '0');
        i++;
    }
    if (nd == 0 || i >= len || s[i] != '.') goto fail;
    i++;
    int64_t us = 0;
    nd = 0;
    while (i < len && s[i] >= '0' && s[i] <= '9') {
        if (++nd > 6) goto fail;            /* finer than 1 us cannot be stored exactly */
        us = us * 10 + (s[i] - '0');
        i++;
    }
    if (nd == 0 || i >= len || s[i] != ')') goto fail;
    for (; nd < 6; nd++) us *= 10;
    f->utime = sec * 1000000 + us;
    i++;

    /* Interface name. */
    rc = PB_CANDUMP_E_IFACE;
    if (i >= len || !is_space(s[i])) goto fail;
    while (i < len && is_space(s[i])) i++;
    size_t n0 = i;
    while (i < len && !is_space(s[i])) {
        if ((unsigned char)s[i] < 0x21 || (unsigned char)s[i] > 0x7e) goto fail;
        i++;
    }
    if (i == n0 || i - n0 >= PB_CANDUMP_IFACE_MAX) { i = n0; goto fail; }
    memcpy(f->iface, s + n0, i - n0);
    f->iface[i - n0] = '\0';

    /* Id: exactly 3 or 8 hex digits, then '#'. */
    rc = PB_CANDUMP_E_ID;
    if (i >= len) goto fail;
    while (i < len && is_space(s[i])) i++;
    size_t id0 = i;
    uint32_t id = 0;
    while (i < len && hexval(s[i]) >= 0) {
        if (i - id0 >= 8) goto fail;
        id = id << 4 | (uint32_t)hexval(s[i]);
        i++;
    }
    if (i >= len || s[i] != '#') goto fail;
    if (i - id0 == 3) {
        if (id > 0x7ff) { i = id0; goto fail; }
        f->id = id;
    } else if (i - id0 == 8) {
        if (id & (PB_CAN_EFF_FLAG | PB_CAN_RTR_FLAG)) { i = id0; goto fail; }
        if (id & PB_CAN_ERR_FLAG) f->error = 1;
        else f->extended = 1;
        f->id = id & 0x1fffffffu;
    } else {
        i = id0;
        goto fail;
    }
    i++;                                    /* past '#' */

    if (i < len && s[i] == '#') {           /* CAN FD (or XL) */
        i++;
        rc = PB_CANDUMP_E_XL;
        if (i < len && s[i] == '#') goto fail;
        rc = PB_CANDUMP_E_DATA;
        if (i >= len || hexval(s[i]) < 0) goto fail;
        f->fd = 1;
        f->fd_flags = (uint8_t)hexval(s[i]);
        i++;
        size_t d0 = i;
        if ((rc = parse_data(s, len, &i, 64, f)) != 0) goto fail;
        rc = PB_CANDUMP_E_LEN;
        if (!fd_len_valid(f->len)) { i = d0; goto fail; }
        if (f->error) { rc = PB_CANDUMP_E_ID; i = id0; goto fail; }  /* no FD error frames */
    } else if (i < len && s[i] == 'R') {    /* remote frame, optional length digit */
        i++;
        f->rtr = 1;
        rc = PB_CANDUMP_E_LEN;
        if (i < len && s[i] >= '0' && s[i] <= '9') {
            if (s[i] > '8') goto fail;
            f->len = (uint8_t)(s[i] - '0');
            i++;
        }
        if (f->error) { rc = PB_CANDUMP_E_ID; i = id0; goto fail; }
    } else {
        if ((rc = parse_data(s, len, &i, 8, f)) != 0) goto fail;
    }

    /* Optional "_X" len8_dlc on an 8-byte classic frame. */
    if (i < len && s[i] == '_') {
        rc = PB_CANDUMP_E_LEN;
        if (f->fd || f->len != 8 || i + 1 >= len) goto fail;
        int d = hexval(s[i + 1]);
        if (d < 9) { i++; goto fail; }
        f->len8_dlc = (uint8_t)d;
        i += 2;
    }

    /* Optional direction flag, then only whitespace. */
    rc = PB_CANDUMP_E_TRAIL;
    if (i < len && !is_space(s[i])) goto fail;
    while (i < len && is_space(s[i])) i++;
    if (i < len && (s[i] == 'T' || s[i] == 'R') && (i + 1 == len || is_space(s[i + 1]))) {
        i++;
        while (i < len && is_space(s[i])) i++;
    }
    if (i < len) goto fail;
    return PB_CANDUMP_FRAME;

fail:
    if (col) *col = i + 1;
    return rc;
}

const char *pb_candump_strerror(int code)
{
    switch (code) {
    case PB_CANDUMP_FRAME:   return "frame";
    case PB_CANDUMP_BLANK:   return "blank line";
    case PB_CANDUMP_E_TIME:  return "bad timestamp, expected (SECONDS.USEC) with 1-6 fractional digits";
    case PB_CANDUMP_E_IFACE: return "bad interface name, expected 1-15 printable characters";
    case PB_CANDUMP_E_ID:    return "bad CAN id, expected 3 hex digits (<= 7FF) or 8 (29-bit or error frame) then '#'";
    case PB_CANDUMP_E_DATA:  return "bad data, expected hex byte pairs optionally separated by '.'";
    case PB_CANDUMP_E_LEN:   return "bad length (more than 8 classic / 64 FD bytes, invalid FD length, remote length > 8 or bad _DLC)";
    case PB_CANDUMP_E_TRAIL: return "unexpected text after the frame";
    case PB_CANDUMP_E_XL:    return "CAN XL frames are not supported";
    default:                 return "unknown candump parse result";
    }
}

int pb_candump_bus(pb_candump_buses_t *b, const char *iface, int *added)
{
    if (added) *added = 0;
    int n = pb_candump_can_index(iface);
    if (n >= 0) return n;
    for (int k = 0; k < b->n; k++)
        if (strcmp(b->names[k], iface) == 0) return PB_CANDUMP_NAMED_BUS_BASE + k;
    if (b->n == PB_CANDUMP_MAX_NAMED) return -1;
    snprintf(b->names[b->n], sizeof b->names[b->n], "%s", iface);
    if (added) *added = 1;
    return PB_CANDUMP_NAMED_BUS_BASE + b->n++;
}

int pb_candump_can_index(const char *iface)
{
    if (!iface || strncmp(iface, "can", 3) != 0) return -1;
    const char *p = iface + 3;
    if (!*p || (p[0] == '0' && p[1])) return -1;    /* "can", "can01" are names, not indices */
    long n = 0;
    for (; *p; p++) {
        if (*p < '0' || *p > '9') return -1;
        n = n * 10 + (*p - '0');
        if (n > 32767) return -1;
    }
    return (int)n;
}
