/* ouster_pcap: UDP datagrams out of a libpcap capture file (the format tcpdump and
 * Wireshark write; not pcapng), with IPv4 fragments reassembled.
 *
 * Reads magic a1b2c3d4 (us) and a1b23c4d (ns), either byte order; link types Ethernet
 * (with 802.1Q VLAN tags), Linux cooked (SLL), BSD loopback and raw IPv4. Everything
 * that is not an IPv4 UDP datagram is skipped and counted. IPv4 fragments are
 * reassembled (up to 8 datagrams in flight, 1 s of capture time each): sensors with
 * 128 beams send 24-33 KB lidar packets, which a 1500-byte MTU splits in ~17 fragments.
 * A truncated last record ends the file with an error naming its byte offset; the
 * datagrams before it have been returned.
 *
 * Ownership: ouster_pcap_t is opaque (open/close). A datagram's payload points into the
 * reader and is valid until the next call. */
#ifndef OUSTER_PCAP_H
#define OUSTER_PCAP_H

#include <stdint.h>
#include <stdio.h>
#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct ouster_pcap ouster_pcap_t;

typedef struct {
    int64_t utime;              /* capture time of the (last fragment's) record, us since epoch */
    int64_t record;             /* 1-based record number of that record */
    uint32_t src_ip, dst_ip;    /* host order */
    uint16_t src_port, dst_port;
    const uint8_t *payload;
    uint32_t len;
} ouster_udp_t;

/* Counters of what was skipped, in the order of ouster_pcap_counter_names. */
enum {
    OUSTER_PCAP_NOT_IPV4, OUSTER_PCAP_NOT_UDP, OUSTER_PCAP_SNAPLEN_CUT, OUSTER_PCAP_BAD_IP,
    OUSTER_PCAP_BAD_UDP, OUSTER_PCAP_FRAGMENTS, OUSTER_PCAP_REASSEMBLED, OUSTER_PCAP_FRAGMENTS_DROPPED,
    OUSTER_PCAP_NCOUNTERS
};
extern const char *const ouster_pcap_counter_names[OUSTER_PCAP_NCOUNTERS];

/* Takes ownership of f (closed by ouster_pcap_close). name is used in messages. */
ouster_pcap_t *ouster_pcap_open_file(FILE *f, const char *name, pb_err_t *err);
ouster_pcap_t *ouster_pcap_open(const char *path, pb_err_t *err);

/* 1: *out holds the next UDP datagram; 0: clean end of file; -1: damaged file (err:
 * "NAME: byte N: what"). */
int ouster_pcap_next(ouster_pcap_t *p, ouster_udp_t *out, pb_err_t *err);

const int64_t *ouster_pcap_counters(const ouster_pcap_t *p);
/* Last skipped-record message ("" if none); *seq increases with each. */
const char *ouster_pcap_last_warning(const ouster_pcap_t *p, int64_t *seq);
void ouster_pcap_close(ouster_pcap_t *p);

#ifdef __cplusplus
}
#endif
#endif
