/* tum: one pose_t as a TUM trajectory line ("t x y z qx qy qz qw", t in seconds).
 * Pure: no I/O beyond the caller's buffer. */
#ifndef PB_TUM_H
#define PB_TUM_H

#include <stddef.h>
#include "portobello_pose_t.h"

/* Formats p into buf (NUL-terminated, newline included). Returns the length, or -1
 * if the pose is not finite or buf is too small (nothing useful written). */
int tum_format(const portobello_pose_t *p, char *buf, size_t size);

#endif
