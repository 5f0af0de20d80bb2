/* ouster-bench: CPU cost of the Ouster driver per frame on the packets of a real capture.
 * Prints one JSON object: median per-frame times (us, thread CPU time) of
 *   copy          memcpy of the frame's lidar packets (the floor any driver pays)
 *   decode        ouster_driver on the packets: columns -> range image, frame closed
 *   decode_encode decode plus LCM encoding of the LIDAR_SCAN (what the live driver does)
 * The packets are replayed --frames times with the frame_id advanced each time. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ouster/core/ouster_driver.h"
#include "ouster/core/ouster_meta.h"
#include "ouster/core/ouster_pcap.h"
#include "pb_opt.h"

typedef struct { int encode; uint8_t *buf; int cap; long bytes; } sink_t;

static void on_scan(const portobello_lidar_scan_t *s, int64_t t, void *user)
{
    sink_t *k = user;
    if (!k->encode) return;
    int n = portobello_lidar_scan_t_encoded_size(s);
    if (n > k->cap) { k->buf = realloc(k->buf, n); k->cap = n; }
    k->bytes = portobello_lidar_scan_t_encode(k->buf, 0, k->cap, s);
}

static double cpu_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e6 + ts.tv_nsec / 1e3;
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double median(double *v, int n) { qsort(v, n, sizeof *v, cmp); return n % 2 ? v[n / 2] : (v[n / 2 - 1] + v[n / 2]) / 2; }

static void usage(FILE *f)
{
    fprintf(f, "usage: ouster-bench --pcap FILE --metadata JSON [--frames N] [--lidar-port 7502]\n"
               "Median CPU time per frame of copying, decoding, decoding+encoding the capture's lidar\n"
               "packets (one frame's worth, replayed N times); prints JSON.\n");
}

int main(int argc, char **argv)
{
    const char *pcap = NULL, *meta_path = NULL;
    long frames = 300, port = 7502;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("pcap", &pcap), PB_OPT_REQUIRED("metadata", &meta_path),
        PB_OPT_LONG("frames", &frames, 3, 1000000), PB_OPT_LONG("lidar-port", &port, 1, 65535), PB_OPT_END,
    };
    int parsed = pb_opt_parse("ouster-bench", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    pb_err_t err;
    ouster_meta_t meta;
    if (ouster_meta_load(meta_path, &meta, &err)) { fprintf(stderr, "ouster-bench: %s\n", err.msg); return 1; }
    ouster_pcap_t *p = ouster_pcap_open(pcap, &err);
    if (!p) { fprintf(stderr, "ouster-bench: %s\n", err.msg); return 1; }
    ouster_layout_t L;
    ouster_layout_init(&L, meta.profile, meta.rows, meta.cols_per_packet);
    int npk = 0, cap = meta.cols_per_frame / meta.cols_per_packet;
    uint8_t *pk = malloc((size_t)cap * L.packet_size), *copy = malloc((size_t)cap * L.packet_size);
    ouster_udp_t u;
    while (npk < cap && ouster_pcap_next(p, &u, &err) == 1)
        if (u.dst_port == port && u.len == L.packet_size) memcpy(pk + (size_t)npk++ * L.packet_size, u.payload, u.len);
    ouster_pcap_close(p);
    if (npk != cap) { fprintf(stderr, "ouster-bench: %d of %d packets of a frame in %s\n", npk, cap, pcap); return 1; }

    double *t_copy = malloc(frames * sizeof(double)), *t_dec = malloc(frames * sizeof(double)),
           *t_enc = malloc(frames * sizeof(double));
    sink_t sink = { 0 };
    ouster_config_t cfg;
    ouster_config_default(&cfg);
    ouster_driver_t *d = ouster_driver_create(&meta, &cfg, on_scan, NULL, &sink, &err);
    if (!d) { fprintf(stderr, "ouster-bench: %s\n", err.msg); return 1; }
    uint16_t fid = 1000;
    for (int pass = 0; pass < 2; pass++) {
        sink.encode = pass;
        for (long f = 0; f < frames; f++) {
            fid++;
            for (int i = 0; i < npk; i++) {   /* next frame: new frame_id (outside the timing) */
                uint8_t *b = pk + (size_t)i * L.packet_size;
                if (L.packet_header) { b[2] = fid & 0xff; b[3] = fid >> 8; }
                else for (int k = 0; k < L.cols_per_packet; k++) { b[k * L.col_size + 10] = fid & 0xff; b[k * L.col_size + 11] = fid >> 8; }
            }
            double t0 = cpu_us();
            for (int i = 0; i < npk; i++)
                ouster_driver_lidar_packet(d, pk + (size_t)i * L.packet_size, L.packet_size, 1700000000000000 + f * 100000);
            double t1 = cpu_us();
            (pass ? t_enc : t_dec)[f] = t1 - t0;
            if (pass == 0) {
                t0 = cpu_us();
                memcpy(copy, pk, (size_t)npk * L.packet_size);
                __asm__ volatile("" ::"r"(copy) : "memory");
                t_copy[f] = cpu_us() - t0;
            }
        }
    }
    long published = ouster_driver_counter(d, "frames"), incomplete = ouster_driver_counter(d, "frames_incomplete");
    printf("{\"sensor\": \"%s\", \"profile\": \"%s\", \"rows\": %d, \"cols\": %d, \"packets_per_frame\": %d, "
           "\"frames\": %ld, \"published\": %ld, \"incomplete\": %ld, \"scan_bytes\": %ld, "
           "\"copy_us\": %.2f, \"decode_us\": %.2f, \"decode_encode_us\": %.2f, \"frame_rate_hz\": %d}\n",
           meta.prod_line[0] ? meta.prod_line : "Ouster", ouster_profile_name(meta.profile), meta.rows,
           meta.cols_per_frame, npk, frames, published, incomplete, sink.bytes, median(t_copy, frames),
           median(t_dec, frames), median(t_enc, frames), meta.frame_rate_hz);
    ouster_driver_destroy(d);
    free(pk); free(copy); free(t_copy); free(t_dec); free(t_enc); free(sink.buf);
    return published == 2 * frames && incomplete == 0 ? 0 : 1;
}
