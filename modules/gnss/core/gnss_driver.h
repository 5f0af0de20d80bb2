/* gnss_driver: a u-blox receiver's byte stream -> position fixes. Pure core: bytes
 * in; fixes, counters and errors (with byte offsets) out through callbacks; no I/O,
 * no clock (time comes only from the receiver's own UTC time).
 *
 * Sources: UBX-NAV-PVT (preferred) and NMEA GGA/RMC (fallback). Rule, on the
 * receiver's UTC time of day (see docs/gnss.md):
 *  - every NAV-PVT is a fix;
 *  - NMEA sentences of one epoch (same time of day) are merged into one candidate
 *    fix (GGA position/height/satellites, RMC date/speed/course, GST accuracy),
 *    decided when GGA and RMC (and GST, once the stream has shown it sends GST)
 *    arrived, the time of day changes, a NAV-PVT arrives, or the input ends;
 *  - a candidate is published when no timed NAV-PVT was seen within
 *    nmea_holdoff_ms of its time (fallback), or when NAV-PVT normally precedes the
 *    NMEA of its epoch on this stream (learned) and this epoch's NAV-PVT is missing
 *    (fill: e.g. a NAV-PVT lost to a bad checksum); otherwise it is suppressed.
 *
 * Ownership: gnss_driver_create returns a driver the caller frees with
 * gnss_driver_destroy. The fix passed to on_fix is valid during the call only. */
#ifndef GNSS_DRIVER_H
#define GNSS_DRIVER_H

#include <stdint.h>

#include "gnss_stream.h"

typedef enum { GNSS_SRC_UBX_NAV_PVT = 0, GNSS_SRC_NMEA = 1 } gnss_source_t;

/* Fix types: the values of portobello.gnss_fix_t FIX_*. */
enum {
    GNSS_FIX_NONE = 0, GNSS_FIX_DEAD_RECKONING = 1, GNSS_FIX_2D = 2, GNSS_FIX_3D = 3,
    GNSS_FIX_GNSS_DR = 4, GNSS_FIX_TIME_ONLY = 5, GNSS_FIX_RTK_FLOAT = 6, GNSS_FIX_RTK_FIXED = 7,
};

/* One fix, in the units of portobello.gnss_fix_t. Unknown values are NaN (num_sv -1). */
typedef struct {
    gnss_source_t source;
    int64_t offset;            /* byte offset of the (first) message it came from */
    int has_utime;             /* receiver UTC date and time valid */
    int64_t utime;             /* us since the UNIX epoch (UTC), when has_utime */
    int8_t fix_type;
    int16_t num_sv;
    double lat_deg, lon_deg, alt_m, alt_msl_m, h_acc_m, v_acc_m;
    double vel_ned_mps[3], speed_mps, heading_deg, heading_acc_deg;
} gnss_fix_out_t;

typedef struct {
    gnss_stream_config_t stream;
    int32_t nmea_holdoff_ms;   /* default 2000 */
} gnss_driver_config_t;

void gnss_driver_config_default(gnss_driver_config_t *c);

/* Named counters, in a fixed order (STATUS counter names). */
typedef enum {
    GNSS_C_UBX_FRAMES = 0, GNSS_C_UBX_NAV_PVT, GNSS_C_NMEA_SENTENCES, GNSS_C_NMEA_GGA, GNSS_C_NMEA_RMC, GNSS_C_NMEA_GST,
    GNSS_C_RTCM3_FRAMES, GNSS_C_FIXES_UBX, GNSS_C_FIXES_NMEA, GNSS_C_NMEA_FILLS, GNSS_C_NMEA_SUPPRESSED,
    GNSS_C_SKIPPED_BYTES,
    /* errors */
    GNSS_C_UBX_BAD_CHECKSUM, GNSS_C_UBX_TOO_LONG, GNSS_C_UBX_TRUNCATED, GNSS_C_NAV_PVT_BAD_LENGTH,
    GNSS_C_NMEA_BAD_CHECKSUM, GNSS_C_NMEA_NO_CHECKSUM, GNSS_C_NMEA_BAD_CHAR, GNSS_C_NMEA_TOO_LONG,
    GNSS_C_NMEA_TRUNCATED, GNSS_C_NMEA_BAD_FIELD, GNSS_C_PVT_NO_UTC, GNSS_C_NMEA_NO_DATE,
    GNSS_C_COUNT
} gnss_counter_t;
#define GNSS_C_FIRST_ERROR GNSS_C_UBX_BAD_CHECKSUM

const char *gnss_counter_name(gnss_counter_t c);

typedef struct {
    void (*on_fix)(void *user, const gnss_fix_out_t *fix);
    /* every counted error: counter, byte offset, one-line detail */
    void (*on_error)(void *user, gnss_counter_t c, int64_t offset, const char *detail);
    void *user;
} gnss_driver_handlers_t;

typedef struct gnss_driver gnss_driver_t;

/* cfg may be NULL (defaults). Returns NULL if out of memory. */
gnss_driver_t *gnss_driver_create(const gnss_driver_config_t *cfg, const gnss_driver_handlers_t *h);
void gnss_driver_destroy(gnss_driver_t *d);

void gnss_driver_feed(gnss_driver_t *d, const uint8_t *data, size_t n);
/* End of input: unfinished frames are reported, the pending NMEA epoch decided. */
void gnss_driver_finish(gnss_driver_t *d);
/* Stop of a live stream: the pending NMEA epoch is decided; bytes of a frame still
 * arriving are left unreported (the stop cut them, not the receiver). */
void gnss_driver_stop(gnss_driver_t *d);

int64_t gnss_driver_counter(const gnss_driver_t *d, gnss_counter_t c);
int64_t gnss_driver_offset(const gnss_driver_t *d);

/* NAV-PVT -> fix (exposed for tests). */
void gnss_fix_from_nav_pvt(const gnss_nav_pvt_t *p, gnss_fix_out_t *fix);

/* Days since 1970-01-01 of a proleptic Gregorian date. */
int64_t gnss_days_from_civil(int y, int m, int d);

#endif
