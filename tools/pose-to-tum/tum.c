/* TUM line of a pose (see tum.h). */
#include "tum.h"

#include <math.h>
#include <stdio.h>

int tum_format(const portobello_pose_t *p, char *buf, size_t size)
{
    for (int i = 0; i < 3; i++) if (!isfinite(p->position[i])) return -1;
    for (int i = 0; i < 4; i++) if (!isfinite(p->orientation[i])) return -1;
    /* TUM orders the quaternion x y z w; pose_t stores w x y z. Seconds with us resolution. */
    long long us = (long long)p->utime;
    long long sec = us / 1000000, frac = us % 1000000;
    if (frac < 0) { frac += 1000000; sec -= 1; }
    int n = snprintf(buf, size, "%lld.%06lld %.6f %.6f %.6f %.9f %.9f %.9f %.9f\n", sec, frac,
                     p->position[0], p->position[1], p->position[2],
                     p->orientation[1], p->orientation[2], p->orientation[3], p->orientation[0]);
    return (n < 0 || (size_t)n >= size) ? -1 : n;
}
