/* can_inputs: what the DBC CANDUMP helper programs (can_bench here, tests/c/can_signal_dump)
 * read before their work: the database, and every frame of a candump -l file in memory.
 * Header-only; each program is one file. */
#ifndef CAN_INPUTS_H
#define CAN_INPUTS_H

#include <stdio.h>
#include <stdlib.h>
#include <sys/types.h>

#include "can/core/can_dbc.h"
#include "pb_candump.h"

typedef struct {
    pb_candump_frame_t *frames;     /* every frame of the file, in order (owned: free both arrays) */
    long *lines;                    /* the 1-based line each frame stood on */
    size_t n;
} can_frames_t;

/* Loads the DBC at dbc_path into *dbc and the frames of the candump -l file at
 * candump_path into *out (lines that are no frame are skipped). Returns 0, or 1 (the
 * exit code) after printing why. */
static int can_inputs_load(const char *dbc_path, const char *candump_path, can_dbc_t **dbc, can_frames_t *out)
{
    pb_err_t err;
    *dbc = can_dbc_load(dbc_path, &err);
    if (!*dbc) { fprintf(stderr, "%s\n", err.msg); return 1; }
    FILE *f = fopen(candump_path, "rb");
    if (!f) { perror(candump_path); can_dbc_destroy(*dbc); return 1; }
    *out = (can_frames_t){ 0 };
    size_t cap = 0, lcap = 0;
    char *line = NULL;
    ssize_t got;
    for (long lineno = 1; (got = getline(&line, &lcap, f)) >= 0; lineno++) {
        pb_candump_frame_t c;
        if (pb_candump_parse(line, (size_t)got, &c, NULL) != PB_CANDUMP_FRAME) continue;
        if (out->n == cap) {
            cap = cap ? cap * 2 : 4096;
            out->frames = realloc(out->frames, cap * sizeof *out->frames);
            out->lines = realloc(out->lines, cap * sizeof *out->lines);
        }
        out->frames[out->n] = c;
        out->lines[out->n++] = lineno;
    }
    free(line);
    fclose(f);
    return 0;
}

#endif
