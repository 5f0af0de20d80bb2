/* What the fuzz targets share: the input as a file, for readers that take a path, and
 * exact-size heap copies, so that AddressSanitizer sees a read one byte past the input.
 * Header-only: every target is one translation unit (see run.sh). */
#ifndef FUZZ_COMMON_H
#define FUZZ_COMMON_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* Writes size bytes to path (created or truncated): 0, or -1 when it cannot be opened. */
static inline int fuzz_write_file(const char *path, const void *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    if (!f) return -1;
    fwrite(data, 1, size, f);
    fclose(f);
    return 0;
}

/* The input as the file /dev/shm/pb_fuzz_NAME_PID<suffix>, the same path for every input
 * of a process (in memory: a million runs write no disk). Returns the path, or NULL when
 * it cannot be written (the target skips that input). */
static inline const char *fuzz_input_file(const char *name, const char *suffix, const uint8_t *data, size_t size)
{
    static char path[128];
    if (!path[0]) snprintf(path, sizeof path, "/dev/shm/pb_fuzz_%s_%d%s", name, (int)getpid(), suffix);
    return fuzz_write_file(path, data, size) == 0 ? path : NULL;
}

/* A heap copy of exactly n bytes (one byte when n is 0, never read); the caller frees it. */
static inline uint8_t *fuzz_copy(const uint8_t *data, size_t n)
{
    uint8_t *p = (uint8_t *)malloc(n ? n : 1);
    memcpy(p, data, n);
    return p;
}

#endif
