/* libpcap file reader with IPv4 reassembly (see ouster_pcap.h). */
#include "ouster_pcap.h"

#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

const char *const ouster_pcap_counter_names[OUSTER_PCAP_NCOUNTERS] = {
    "pcap_skipped_not_ipv4", "pcap_skipped_not_udp", "pcap_skipped_snaplen_cut", "pcap_skipped_bad_ip",
    "pcap_skipped_bad_udp", "pcap_ip_fragments", "pcap_datagrams_reassembled", "pcap_fragments_dropped",
};

#define MAX_RECORD (256u * 1024)
#define NSLOTS 8
#define REASM_MAX 65535
#define REASM_TIMEOUT_US 1000000

enum { LINK_NULL = 0, LINK_ETHERNET = 1, LINK_RAW = 101, LINK_SLL = 113, LINK_IPV4 = 228 };

typedef struct {
    int used;
    uint32_t src, dst;
    uint16_t id;
    int64_t first_utime, last_record;
    int total;                      /* payload length once the last fragment is seen, else -1 */
    uint8_t have[(REASM_MAX + 7) / 8 / 8 + 1];   /* one bit per 8-byte block */
    uint8_t data[REASM_MAX + 8];
} slot_t;

struct ouster_pcap {
    FILE *f;
    char name[256];
    int swap, nanos;
    uint32_t linktype, snaplen;
    int64_t offset, record;
    uint8_t *rec;
    slot_t *slots;
    uint8_t *out;                   /* reassembled datagram handed out */
    int64_t counters[OUSTER_PCAP_NCOUNTERS];
    char warning[300];
    int64_t warning_seq;
};

static uint32_t u32(const ouster_pcap_t *p, const uint8_t *b)
{
    return p->swap ? (uint32_t)b[0] << 24 | (uint32_t)b[1] << 16 | (uint32_t)b[2] << 8 | b[3]
                   : (uint32_t)b[3] << 24 | (uint32_t)b[2] << 16 | (uint32_t)b[1] << 8 | b[0];
}
static uint16_t be16(const uint8_t *b) { return (uint16_t)(b[0] << 8 | b[1]); }
static uint32_t be32(const uint8_t *b) { return (uint32_t)b[0] << 24 | (uint32_t)b[1] << 16 | (uint32_t)b[2] << 8 | b[3]; }

static void skip(ouster_pcap_t *p, int counter, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void skip(ouster_pcap_t *p, int counter, const char *fmt, ...)
{
    p->counters[counter]++;
    int n = snprintf(p->warning, sizeof p->warning, "%s: record %lld: ", p->name, (long long)p->record);
    va_list ap;
    va_start(ap, fmt);
    if (n > 0 && (size_t)n < sizeof p->warning) vsnprintf(p->warning + n, sizeof p->warning - n, fmt, ap);
    va_end(ap);
    p->warning_seq++;
}

ouster_pcap_t *ouster_pcap_open_file(FILE *f, const char *name, pb_err_t *err)
{
    uint8_t h[24];
    if (fread(h, 1, 24, f) != 24) {
        pb_err_set(err, "%s: byte 0: shorter than a pcap file header (24 bytes)", name);
        fclose(f);
        return NULL;
    }
    uint32_t magic = (uint32_t)h[0] | (uint32_t)h[1] << 8 | (uint32_t)h[2] << 16 | (uint32_t)h[3] << 24;
    int swap = 0, nanos = 0;
    if (magic == 0xa1b2c3d4) { }
    else if (magic == 0xd4c3b2a1) swap = 1;
    else if (magic == 0xa1b23c4d) nanos = 1;
    else if (magic == 0x4d3cb2a1) { swap = 1; nanos = 1; }
    else {
        pb_err_set(err, "%s: byte 0: magic %08x is not a pcap file%s", name, magic,
                   magic == 0x0a0d0d0a ? " (this is pcapng: convert it with `editcap -F pcap IN OUT`)" : "");
        fclose(f);
        return NULL;
    }
    ouster_pcap_t *p = calloc(1, sizeof *p);
    if (p) { p->rec = malloc(MAX_RECORD); p->slots = calloc(NSLOTS, sizeof *p->slots); p->out = malloc(REASM_MAX + 8); }
    if (!p || !p->rec || !p->slots || !p->out) {
        if (p) { free(p->rec); free(p->slots); free(p->out); free(p); }
        pb_err_set(err, "%s: out of memory", name);
        fclose(f);
        return NULL;
    }
    p->f = f;
    snprintf(p->name, sizeof p->name, "%s", name);
    p->swap = swap;
    p->nanos = nanos;
    p->snaplen = u32(p, h + 16);
    p->linktype = u32(p, h + 20) & 0x0FFFFFFF;
    p->offset = 24;
    if (p->linktype != LINK_NULL && p->linktype != LINK_ETHERNET && p->linktype != LINK_RAW &&
        p->linktype != LINK_SLL && p->linktype != LINK_IPV4) {
        pb_err_set(err, "%s: byte 20: link type %u not supported (Ethernet, Linux cooked, loopback, raw IP)", name,
                   p->linktype);
        ouster_pcap_close(p);
        return NULL;
    }
    return p;
}

ouster_pcap_t *ouster_pcap_open(const char *path, pb_err_t *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) { pb_err_set(err, "%s: %s", path, strerror(errno)); return NULL; }
    return ouster_pcap_open_file(f, path, err);
}

void ouster_pcap_close(ouster_pcap_t *p)
{
    if (!p) return;
    if (p->f) fclose(p->f);
    free(p->rec); free(p->slots); free(p->out);
    free(p);
}

const int64_t *ouster_pcap_counters(const ouster_pcap_t *p) { return p->counters; }

const char *ouster_pcap_last_warning(const ouster_pcap_t *p, int64_t *seq)
{
    if (seq) *seq = p->warning_seq;
    return p->warning;
}

/* Link layer -> IPv4 header, or NULL (counted). */
static const uint8_t *ip_of(ouster_pcap_t *p, const uint8_t *b, uint32_t len, uint32_t *iplen)
{
    uint32_t off;
    uint16_t type;
    switch (p->linktype) {
    case LINK_ETHERNET:
        if (len < 14) { skip(p, OUSTER_PCAP_NOT_IPV4, "Ethernet frame of %u bytes", len); return NULL; }
        off = 12;
        type = be16(b + off);
        while ((type == 0x8100 || type == 0x88a8) && off + 6 <= len) { off += 4; type = be16(b + off); }
        off += 2;
        if (type != 0x0800 || off > len) { skip(p, OUSTER_PCAP_NOT_IPV4, "ethertype 0x%04x, not IPv4", type); return NULL; }
        break;
    case LINK_SLL:
        if (len < 16 || be16(b + 14) != 0x0800) { skip(p, OUSTER_PCAP_NOT_IPV4, "Linux cooked record, not IPv4"); return NULL; }
        off = 16;
        break;
    case LINK_NULL: {
        if (len < 4) { skip(p, OUSTER_PCAP_NOT_IPV4, "loopback record of %u bytes", len); return NULL; }
        uint32_t fam = (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
        if (fam != 2 && be32(b) != 2) { skip(p, OUSTER_PCAP_NOT_IPV4, "loopback family %u, not IPv4", fam); return NULL; }
        off = 4;
        break;
    }
    default:
        off = 0;
    }
    if (len - off < 20 || (b[off] >> 4) != 4) { skip(p, OUSTER_PCAP_NOT_IPV4, "not an IPv4 packet"); return NULL; }
    *iplen = len - off;
    return b + off;
}

static slot_t *slot_for(ouster_pcap_t *p, uint32_t src, uint32_t dst, uint16_t id, int64_t utime)
{
    slot_t *free_slot = NULL, *oldest = NULL;
    for (int i = 0; i < NSLOTS; i++) {
        slot_t *s = &p->slots[i];
        if (s->used && utime - s->first_utime > REASM_TIMEOUT_US) {
            s->used = 0;
            skip(p, OUSTER_PCAP_FRAGMENTS_DROPPED, "IPv4 datagram id %u never completed within 1 s", s->id);
        }
        if (s->used && s->src == src && s->dst == dst && s->id == id) return s;
        if (!s->used && !free_slot) free_slot = s;
        if (s->used && (!oldest || s->first_utime < oldest->first_utime)) oldest = s;
    }
    if (!free_slot) {
        skip(p, OUSTER_PCAP_FRAGMENTS_DROPPED, "IPv4 datagram id %u dropped: more than %d in reassembly", oldest->id,
             NSLOTS);
        free_slot = oldest;
    }
    free_slot->used = 1;
    free_slot->src = src;
    free_slot->dst = dst;
    free_slot->id = id;
    free_slot->first_utime = utime;
    free_slot->total = -1;
    memset(free_slot->have, 0, sizeof free_slot->have);
    return free_slot;
}

/* Adds a fragment; returns the reassembled IP payload length when complete, else -1. */
static int reassemble(ouster_pcap_t *p, const uint8_t *ip, uint32_t ihl, uint32_t tot, int64_t utime,
                      const uint8_t **payload)
{
    uint16_t frag = be16(ip + 6);
    uint32_t off = (uint32_t)(frag & 0x1fff) * 8, n = tot - ihl;
    int more = (frag & 0x2000) != 0;
    p->counters[OUSTER_PCAP_FRAGMENTS]++;
    if (off + n > REASM_MAX || (more && n % 8 != 0) || n == 0) {
        skip(p, OUSTER_PCAP_BAD_IP, "IPv4 fragment at offset %u of %u bytes is invalid", off, n);
        return -1;
    }
    slot_t *s = slot_for(p, be32(ip + 12), be32(ip + 16), be16(ip + 4), utime);
    memcpy(s->data + off, ip + ihl, n);
    for (uint32_t blk = off / 8; blk < (off + n + 7) / 8; blk++) s->have[blk / 8] |= (uint8_t)(1u << (blk % 8));
    if (!more) s->total = (int)(off + n);
    if (s->total < 0) return -1;
    for (uint32_t blk = 0; blk < ((uint32_t)s->total + 7) / 8; blk++)
        if (!(s->have[blk / 8] & (1u << (blk % 8)))) return -1;
    memcpy(p->out, s->data, s->total);
    s->used = 0;
    p->counters[OUSTER_PCAP_REASSEMBLED]++;
    *payload = p->out;
    return s->total;
}

int ouster_pcap_next(ouster_pcap_t *p, ouster_udp_t *out, pb_err_t *err)
{
    for (;;) {
        uint8_t h[16];
        size_t got = fread(h, 1, 16, p->f);
        if (got == 0 && feof(p->f)) return 0;
        if (got != 16)
            return pb_err_set(err, "%s: byte %lld: truncated record header (%zu of 16 bytes)", p->name,
                              (long long)p->offset, got);
        uint32_t sec = u32(p, h), frac = u32(p, h + 4), incl = u32(p, h + 8), orig = u32(p, h + 12);
        if (incl > MAX_RECORD)
            return pb_err_set(err, "%s: byte %lld: record of %u bytes (damaged file?)", p->name, (long long)p->offset,
                              incl);
        if (fread(p->rec, 1, incl, p->f) != incl)
            return pb_err_set(err, "%s: byte %lld: record of %u bytes is cut short by the end of the file", p->name,
                              (long long)p->offset, incl);
        p->offset += 16 + incl;
        p->record++;
        int64_t utime = (int64_t)sec * 1000000 + (p->nanos ? frac / 1000 : frac);
        if (incl < orig) { skip(p, OUSTER_PCAP_SNAPLEN_CUT, "captured %u of %u bytes (snaplen)", incl, orig); continue; }

        uint32_t iplen;
        const uint8_t *ip = ip_of(p, p->rec, incl, &iplen);
        if (!ip) continue;
        uint32_t ihl = (ip[0] & 0x0f) * 4u, tot = be16(ip + 2);
        if (ihl < 20 || tot < ihl || tot > iplen) {
            skip(p, OUSTER_PCAP_BAD_IP, "IPv4 header lengths %u/%u do not fit %u bytes", ihl, tot, iplen);
            continue;
        }
        if (ip[9] != 17) { skip(p, OUSTER_PCAP_NOT_UDP, "IP protocol %u, not UDP", ip[9]); continue; }
        const uint8_t *udp = ip + ihl;
        uint32_t ulen_avail = tot - ihl;
        uint16_t frag = be16(ip + 6);
        if (frag & 0x3fff) {
            int n = reassemble(p, ip, ihl, tot, utime, &udp);
            if (n < 0) continue;
            ulen_avail = (uint32_t)n;
        }
        if (ulen_avail < 8) { skip(p, OUSTER_PCAP_BAD_UDP, "UDP header cut (%u bytes)", ulen_avail); continue; }
        uint32_t ulen = be16(udp + 4);
        if (ulen < 8 || ulen > ulen_avail) {
            skip(p, OUSTER_PCAP_BAD_UDP, "UDP length %u does not fit the %u bytes of the IP payload", ulen, ulen_avail);
            continue;
        }
        out->utime = utime;
        out->record = p->record;
        out->src_ip = be32(ip + 12);
        out->dst_ip = be32(ip + 16);
        out->src_port = be16(udp);
        out->dst_port = be16(udp + 2);
        out->payload = udp + 8;
        out->len = ulen - 8;
        return 1;
    }
}
