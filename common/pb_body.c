/* pb_body: sample points on agents' bodies (see pb_body.h). Offsets are in the
 * agent's frame: x forward, y left, z up from its ground origin, metres. */
#include "pb_body.h"

#include <math.h>
#include <string.h>

typedef struct { const char *name; float x, y, z; } body_pt_t;

/* An adult standing (1.75 m): ankles 0.2 m up so that a curb (0.15 m) does not hide the feet of
 * someone standing behind it, hands hanging beside the hips. */
static const body_pt_t pedestrian[] = {
    { "left_foot", 0, 0.10f, 0.20f }, { "right_foot", 0, -0.10f, 0.20f },
    { "left_knee", 0, 0.10f, 0.50f }, { "right_knee", 0, -0.10f, 0.50f },
    { "left_hip", 0, 0.15f, 0.95f }, { "right_hip", 0, -0.15f, 0.95f },
    { "left_hand", 0, 0.30f, 0.80f }, { "right_hand", 0, -0.30f, 0.80f },
    { "left_shoulder", 0, 0.20f, 1.42f }, { "right_shoulder", 0, -0.20f, 1.42f },
    { "head", 0, 0, 1.65f },
};
/* A rider on a bicycle (1.75 m long). */
static const body_pt_t cyclist[] = {
    { "front_wheel", 0.55f, 0, 0.35f }, { "rear_wheel", -0.55f, 0, 0.35f },
    { "left_knee", 0.15f, 0.15f, 0.65f }, { "right_knee", 0.15f, -0.15f, 0.65f },
    { "left_hip", -0.20f, 0.12f, 1.00f }, { "right_hip", -0.20f, -0.12f, 1.00f },
    { "left_hand", 0.45f, 0.25f, 1.05f }, { "right_hand", 0.45f, -0.25f, 1.05f },
    { "left_shoulder", 0.05f, 0.20f, 1.45f }, { "right_shoulder", 0.05f, -0.20f, 1.45f },
    { "head", 0.10f, 0, 1.70f },
};
/* A car (4.5 x 1.8 x 1.5 m) whose origin is the centre of its footprint. */
static const body_pt_t vehicle[] = {
    { "front_left_low", 2.1f, 0.85f, 0.40f }, { "front_right_low", 2.1f, -0.85f, 0.40f },
    { "rear_left_low", -2.1f, 0.85f, 0.40f }, { "rear_right_low", -2.1f, -0.85f, 0.40f },
    { "front_left_high", 1.2f, 0.80f, 1.30f }, { "front_right_high", 1.2f, -0.80f, 1.30f },
    { "rear_left_high", -1.6f, 0.80f, 1.30f }, { "rear_right_high", -1.6f, -0.80f, 1.30f },
    { "front", 2.2f, 0, 0.70f }, { "rear", -2.2f, 0, 0.70f },
    { "left", 0, 0.88f, 0.80f }, { "right", 0, -0.88f, 0.80f },
    { "roof", -0.2f, 0, 1.45f },
};
/* Anything else: a 1 m object. */
static const body_pt_t object[] = {
    { "centre", 0, 0, 0.50f }, { "front_left", 0.4f, 0.4f, 0.90f }, { "front_right", 0.4f, -0.4f, 0.90f },
    { "rear_left", -0.4f, 0.4f, 0.90f }, { "rear_right", -0.4f, -0.4f, 0.90f },
};

static const body_pt_t *model_of(const char *kind, int *n)
{
#define M(a) (*n = (int)(sizeof a / sizeof a[0]), a)
    if (kind && !strcmp(kind, "pedestrian")) return M(pedestrian);
    if (kind && !strcmp(kind, "cyclist")) return M(cyclist);
    if (kind && !strcmp(kind, "vehicle")) return M(vehicle);
    return M(object);
#undef M
}

int pb_body_samples(const char *kind, const double pos[3], double yaw, float *x, float *y, float *z)
{
    int n;
    const body_pt_t *m = model_of(kind, &n);
    double c = cos(yaw), s = sin(yaw);
    for (int i = 0; i < n; i++) {
        x[i] = (float)(pos[0] + c * m[i].x - s * m[i].y);
        y[i] = (float)(pos[1] + s * m[i].x + c * m[i].y);
        z[i] = (float)(pos[2] + m[i].z);
    }
    return n;
}

const char *pb_body_sample_name(const char *kind, int i)
{
    int n;
    const body_pt_t *m = model_of(kind, &n);
    return i >= 0 && i < n ? m[i].name : "";
}
