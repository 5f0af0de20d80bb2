/* thing_t: one field of every kind pb_cfg_read fills, and its schema (length required),
 * read by the config unit test (tests/c/test_config.c) and the config fuzz target. */
#ifndef CFG_THING_H
#define CFG_THING_H

#include <stddef.h>

#include "pb_config.h"

typedef struct {
    double length;
    long count;
    int enabled;
    char name[16];
    double xyz[3];
    const pb_cfg_node_t *extra;
} thing_t;

static const pb_cfg_field_t THING[] = {
    { "length", PB_CFG_DOUBLE, offsetof(thing_t, length), 0, 1 },
    { "count", PB_CFG_INT, offsetof(thing_t, count), 0, 0 },
    { "enabled", PB_CFG_BOOL, offsetof(thing_t, enabled), 0, 0 },
    { "name", PB_CFG_STRING, offsetof(thing_t, name), 16, 0 },
    { "xyz", PB_CFG_DOUBLES, offsetof(thing_t, xyz), 3, 0 },
    { "extra", PB_CFG_NODE, offsetof(thing_t, extra), 0, 0 },
    PB_CFG_END,
};

#endif
