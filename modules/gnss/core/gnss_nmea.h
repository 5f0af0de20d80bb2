/* gnss_nmea: NMEA 0183 sentences ($..GGA, $..RMC, $..GST) with their *hh checksum. Pure
 * functions, no I/O, no locale (numbers are parsed here, not by strtod).
 *
 * Sentence: '$', address (talker + type, e.g. GNGGA), ',' fields, '*', two hex digits
 * (XOR of every byte between '$' and '*'), CR LF. */
#ifndef GNSS_NMEA_H
#define GNSS_NMEA_H

#include <stddef.h>
#include <stdint.h>

#define GNSS_NMEA_MAX_LEN_DEFAULT 200   /* NMEA says 82; u-blox PUBX and NMEA 4.11 run longer */
#define GNSS_NMEA_MAX_FIELDS 40

typedef enum {
    GNSS_NMEA_SENTENCE = 0,    /* a whole sentence with a good checksum */
    GNSS_NMEA_NEED_MORE,       /* may be a sentence: more bytes needed */
    GNSS_NMEA_NOT_START,       /* not '$' followed by an address and ',' (not a sentence) */
    GNSS_NMEA_BAD_CHECKSUM,    /* *hh does not match */
    GNSS_NMEA_NO_CHECKSUM,     /* line ended without *hh, or *hh not hex */
    GNSS_NMEA_BAD_CHAR,        /* a byte outside printable ASCII inside the sentence */
    GNSS_NMEA_TOO_LONG,        /* no end within the maximum length */
    GNSS_NMEA_TRUNCATED,       /* a new '$' began before this sentence ended */
} gnss_nmea_result_t;

typedef struct {
    const char *body;          /* after '$' up to (not including) '*': points into the buffer */
    size_t body_len;
    char address[16];          /* "GNGGA" */
    const char *type;          /* last three letters of address ("GGA"), inside address */
    size_t total;              /* bytes to consume, including CR/LF that follow */
    size_t error_at;           /* on an error: index of the offending byte */
    uint8_t ck_recv, ck_calc;
} gnss_nmea_sentence_t;

/* Checks whether buf[0..avail) starts with a sentence of at most max_len bytes. at_end:
 * no more bytes will come (a sentence may then end right after *hh). */
gnss_nmea_result_t gnss_nmea_sentence_check(const char *buf, size_t avail, size_t max_len,
                                            int at_end, gnss_nmea_sentence_t *s);

typedef struct {
    int32_t tod_ms;            /* UTC time of day, ms; -1 if empty */
    int has_pos;
    double lat_deg, lon_deg;
    int quality;               /* 0 invalid, 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float, 6 DR, ... ; -1 empty */
    int num_sv;                /* -1 if empty */
    double hdop, alt_msl_m, geoid_sep_m;   /* NaN if empty */
} gnss_nmea_gga_t;

typedef struct {
    int32_t tod_ms;            /* -1 if empty */
    char status;               /* 'A' valid, 'V' warning, 0 empty */
    int has_pos;
    double lat_deg, lon_deg;
    double speed_knots, course_deg;        /* NaN if empty */
    int has_date;
    int year, month, day;
    char mode;                 /* posMode (NMEA 2.3+): A, D, E, F, R, N, ...; 0 if absent */
} gnss_nmea_rmc_t;

typedef struct {
    int32_t tod_ms;            /* -1 if empty */
    double rms_range_m;        /* RMS of the pseudorange residuals */
    double std_major_m, std_minor_m, orient_deg;   /* error ellipse (1 sigma) */
    double std_lat_m, std_lon_m, std_alt_m;        /* 1 sigma per axis; NaN if empty */
} gnss_nmea_gst_t;

/* Parse the body of a sentence already checked. Return 0, or -1 with *bad_field the
 * 1-based index of the first malformed field. */
int gnss_nmea_parse_gga(const gnss_nmea_sentence_t *s, gnss_nmea_gga_t *gga, int *bad_field);
int gnss_nmea_parse_rmc(const gnss_nmea_sentence_t *s, gnss_nmea_rmc_t *rmc, int *bad_field);
int gnss_nmea_parse_gst(const gnss_nmea_sentence_t *s, gnss_nmea_gst_t *gst, int *bad_field);

#endif
