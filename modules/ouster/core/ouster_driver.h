/* ouster_driver: the pure core of the Ouster driver. UDP payloads in (with the time they
 * were received), LIDAR_SCAN range images and IMU samples out, through callbacks.
 *
 * Frame assembly: a column goes to pixel column measurement_id of the frame named by
 * its frame_id (range image in firing order, "staggered", as lidar_scan_t wants). A
 * frame is published as soon as every column of the column window has arrived, or when
 * a column of another frame_id arrives, or at ouster_driver_flush / _tick (timeout).
 * Columns that never arrived keep range 0 (no return) and a nominal col_offset_us;
 * they are counted (columns_missing, frames_incomplete).
 *
 * Time: sensor timestamps are ns on the sensor's clock. Values >= 1e18 ns are taken as
 * UNIX time (PTP or GPS synced sensor). Otherwise (TIME_FROM_INTERNAL_OSC: ns since
 * boot) utime = sensor time + offset, offset = the smallest (receive time - sensor time)
 * seen over the previous 10 s window of receive time (the least-delayed packet; in the
 * first window the first packet's), reset when the sensor clock jumps by more than 1 s
 * (reboot). The offset changes only at window ends. Lidar and IMU share the offset,
 * so their relative timing is the sensor's own.
 *
 * Bad input is never fatal: each rejected packet or column is counted under a reason
 * (ouster_driver_counters) and the last one described in ouster_driver_last_error.
 *
 * Ownership: the driver owns its scan buffers; a scan or IMU passed to a callback is
 * valid only during the call. The metadata is copied. */
#ifndef OUSTER_DRIVER_H
#define OUSTER_DRIVER_H

#include <stddef.h>
#include <stdint.h>
#include "ouster_meta.h"
#include "ouster_packet.h"
#include "pb_err.h"
#include "portobello_imu_t.h"
#include "portobello_lidar_scan_t.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum { OUSTER_SIGNAL_AUTO = 0, OUSTER_SIGNAL_ON, OUSTER_SIGNAL_OFF } ouster_signal_mode_t;

typedef struct {
    int which_return;               /* 1 (default) or 2: return of the DUAL profile to publish */
    ouster_signal_mode_t signal;    /* AUTO: signal and near-IR when the sweep fits the
                                       600 KB budget (rows x cols <= 64 x 1024) */
    int check_sensor_id;            /* 1: reject non-legacy packets whose init_id/prod_sn
                                       differ from the metadata's (default 1) */
} ouster_config_t;

void ouster_config_default(ouster_config_t *cfg);

typedef void (*ouster_scan_fn)(const portobello_lidar_scan_t *scan, int64_t recv_utime, void *user);
typedef void (*ouster_imu_fn)(const portobello_imu_t *imu, int64_t recv_utime, void *user);

typedef struct ouster_driver ouster_driver_t;

/* Returns NULL with err set if the metadata cannot be used (e.g. more columns than supported). */
ouster_driver_t *ouster_driver_create(const ouster_meta_t *meta, const ouster_config_t *cfg,
                                      ouster_scan_fn on_scan, ouster_imu_fn on_imu, void *user, pb_err_t *err);
void ouster_driver_destroy(ouster_driver_t *d);

/* One UDP payload from the lidar port / the IMU port, received at recv_utime (us since
 * epoch: pcap capture time or socket receive time). May call on_scan / on_imu. */
void ouster_driver_lidar_packet(ouster_driver_t *d, const uint8_t *buf, size_t len, int64_t recv_utime);
void ouster_driver_imu_packet(ouster_driver_t *d, const uint8_t *buf, size_t len, int64_t recv_utime);

/* Publishes the frame being assembled, if any (end of input). */
void ouster_driver_flush(ouster_driver_t *d, int64_t now_utime);
/* Live: publishes a frame that has had no new column for 1.5 frame periods. */
void ouster_driver_tick(ouster_driver_t *d, int64_t now_utime);

/* Named counters: packets, frames, and rejects by reason. Returns the number; names and
 * values are valid until the driver is destroyed. */
int ouster_driver_counters(const ouster_driver_t *d, const char *const **names, const int64_t **values);
int64_t ouster_driver_counter(const ouster_driver_t *d, const char *name);
/* Last reject or warning, "" if none; *seq increases with every new message. */
const char *ouster_driver_last_error(const ouster_driver_t *d, int64_t *seq);

const ouster_layout_t *ouster_driver_layout(const ouster_driver_t *d);

#ifdef __cplusplus
}
#endif
#endif
