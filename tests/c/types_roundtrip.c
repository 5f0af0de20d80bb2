/* types_roundtrip IN.lcm OUT.lcm: decodes every event of IN with the C type named
 * by its channel (e.g. "lidar_scan_t") and re-encodes it into OUT, so a test can
 * check that C reproduces the bytes Python encoded, for every type. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pb_log.h"
#include "portobello_agent_occlusion_t.h"
#include "portobello_agent_t.h"
#include "portobello_agents_t.h"
#include "portobello_can_frame_t.h"
#include "portobello_command_state_t.h"
#include "portobello_gnss_fix_t.h"
#include "portobello_head_pose_t.h"
#include "portobello_imu_t.h"
#include "portobello_input_status_t.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_occlusion_t.h"
#include "portobello_participant_input_t.h"
#include "portobello_pose_t.h"
#include "portobello_scenario_event_t.h"
#include "portobello_status_t.h"
#include "portobello_supervisor_command_t.h"
#include "portobello_supervisor_t.h"
#include "portobello_vehicle_speed_t.h"

#define TYPES(X) X(agent_occlusion_t) X(agent_t) X(agents_t) X(can_frame_t) X(command_state_t) X(gnss_fix_t) X(head_pose_t) \
    X(imu_t) X(input_status_t) X(lidar_scan_t) X(occlusion_t) X(participant_input_t) X(pose_t) \
    X(scenario_event_t) X(status_t) X(supervisor_command_t) X(supervisor_t) X(vehicle_speed_t)

/* Decode then re-encode; returns the new size or -1. */
#define ROUNDTRIP(T) \
    static int rt_##T(const uint8_t *in, int len, uint8_t **out) { \
        portobello_##T m; \
        if (portobello_##T##_decode(in, 0, len, &m) != len) return -1; \
        int n = portobello_##T##_encoded_size(&m); \
        *out = malloc(n); \
        int w = portobello_##T##_encode(*out, 0, n, &m); \
        portobello_##T##_decode_cleanup(&m); \
        return w == n ? n : -1; \
    }
TYPES(ROUNDTRIP)

int main(int argc, char **argv)
{
    if (argc != 3) { fprintf(stderr, "usage: types_roundtrip IN.lcm OUT.lcm\n"); return 2; }
    pb_err_t err;
    pb_log_t *in = pb_log_open_read(argv[1], &err), *out = in ? pb_log_open_write(argv[2], &err) : NULL;
    if (!in || !out) { fprintf(stderr, "%s\n", err.msg); return 1; }
    pb_event_t ev;
    int r, n = 0;
    while ((r = pb_log_next(in, &ev, &err)) == 1) {
        uint8_t *buf = NULL;
        int len = -2;
#define DISPATCH(T) if (strcmp(ev.channel, #T) == 0) len = rt_##T(ev.data, ev.datalen, &buf);
        TYPES(DISPATCH)
        if (len == -2) { fprintf(stderr, "unknown type channel %s\n", ev.channel); return 1; }
        if (len < 0) { fprintf(stderr, "event %lld (%s): C decode/encode failed\n", (long long)ev.eventnum, ev.channel); return 1; }
        pb_log_write(out, ev.timestamp, ev.channel, buf, len, NULL);
        free(buf);
        n++;
    }
    if (r < 0) { fprintf(stderr, "%s\n", err.msg); return 1; }
    pb_log_close(in, NULL);
    if (pb_log_close(out, &err) != 0) { fprintf(stderr, "%s\n", err.msg); return 1; }
    printf("%d messages round-tripped\n", n);
    return 0;
}
