/* gnss_stream: one receiver byte stream (UBX, NMEA and RTCM3 interleaved on one
 * port) cut into frames. Pure core: bytes in, frames and counted errors with their
 * absolute byte offsets out, through callbacks; no I/O, no clock.
 *
 * Resynchronisation: after a bad frame (checksum, length, truncation) scanning
 * resumes at the byte after the bad frame's first sync byte, so a good frame that
 * starts inside a bad one's claimed length is still found. A UBX length above
 * max_ubx_payload is refused from the header alone. Bytes that start no frame are
 * skipped and reported as runs (offset, count).
 *
 * Ownership: gnss_stream_create returns a stream the caller frees with
 * gnss_stream_destroy. Pointers passed to callbacks are valid during the call only. */
#ifndef GNSS_STREAM_H
#define GNSS_STREAM_H

#include <stddef.h>
#include <stdint.h>

#include "gnss_nmea.h"
#include "gnss_ubx.h"

typedef enum {
    GNSS_ERR_UBX_BAD_CHECKSUM = 0,
    GNSS_ERR_UBX_TOO_LONG,
    GNSS_ERR_UBX_TRUNCATED,
    GNSS_ERR_NMEA_BAD_CHECKSUM,
    GNSS_ERR_NMEA_NO_CHECKSUM,
    GNSS_ERR_NMEA_BAD_CHAR,
    GNSS_ERR_NMEA_TOO_LONG,
    GNSS_ERR_NMEA_TRUNCATED,
    GNSS_ERR_COUNT
} gnss_stream_error_t;

/* STATUS counter name of each error ("ubx_bad_checksum", ...). */
const char *gnss_stream_error_name(gnss_stream_error_t e);

typedef struct {
    void (*on_ubx)(void *user, int64_t offset, const gnss_ubx_frame_t *f);
    void (*on_nmea)(void *user, int64_t offset, const gnss_nmea_sentence_t *s);
    void (*on_rtcm3)(void *user, int64_t offset, int msg_type, size_t total);
    /* detail: one line, e.g. "checksum 73 8e, computed 73 8d (class 01 id 07, 92 bytes)" */
    void (*on_error)(void *user, int64_t offset, gnss_stream_error_t e, const char *detail);
    void (*on_skip)(void *user, int64_t offset, int64_t nbytes);
    void *user;
} gnss_stream_handlers_t;

typedef struct {
    size_t max_ubx_payload;    /* default 8192 */
    size_t max_nmea_len;       /* default GNSS_NMEA_MAX_LEN_DEFAULT */
} gnss_stream_config_t;

void gnss_stream_config_default(gnss_stream_config_t *c);

typedef struct gnss_stream gnss_stream_t;

/* cfg may be NULL (defaults). Returns NULL if out of memory. */
gnss_stream_t *gnss_stream_create(const gnss_stream_config_t *cfg, const gnss_stream_handlers_t *h);
void gnss_stream_destroy(gnss_stream_t *s);

/* Any chunking of the same bytes gives the same callbacks in the same order. */
void gnss_stream_feed(gnss_stream_t *s, const uint8_t *data, size_t n);
/* End of input: an unfinished frame is reported as truncated and scanning goes on
 * past its first byte. The stream may then be fed again (a new segment). */
void gnss_stream_finish(gnss_stream_t *s);

/* Bytes fed so far. */
int64_t gnss_stream_offset(const gnss_stream_t *s);

/* RTCM3 frame check (0xD3, 10-bit length, CRC-24Q): 1 frame (*total set), 0 need
 * more, -1 not a frame. */
int gnss_rtcm3_check(const uint8_t *buf, size_t avail, size_t *total, int *msg_type);

#endif
