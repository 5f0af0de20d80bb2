/* libFuzzer target: a pcap file, arbitrary bytes (Ethernet/SLL/loopback/raw framing,
 * IPv4 fragments). Returned datagrams must lie inside the reader's buffers (ASan) and
 * be at most 65535 bytes; a damaged file must be reported with a message.
 * fuzz-sources: modules/ouster/core/ouster_pcap.c common/pb_err.c */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ouster/core/ouster_pcap.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size == 0) return 0;
    FILE *f = fmemopen((void *)data, size, "rb");
    if (!f) return 0;
    pb_err_t err = { { 0 } };
    ouster_pcap_t *p = ouster_pcap_open_file(f, "fuzz.pcap", &err);
    if (!p) { if (err.msg[0] == 0) abort(); return 0; }
    ouster_udp_t u;
    int rc;
    volatile uint8_t sink = 0;
    while ((rc = ouster_pcap_next(p, &u, &err)) == 1) {
        if (u.len > 65535) abort();
        for (uint32_t i = 0; i < u.len; i++) sink ^= u.payload[i];
    }
    if (rc < 0 && err.msg[0] == 0) abort();
    ouster_pcap_close(p);
    (void)sink;
    return 0;
}
