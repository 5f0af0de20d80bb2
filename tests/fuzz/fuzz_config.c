/* libFuzzer target: the YAML config loader and schema reader on arbitrary bytes.
 * fuzz-sources: common/pb_config.c common/pb_err.c */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "pb_config.h"

typedef struct {
    double d;
    long i;
    int b;
    char s[8];
    double v[3];
    const pb_cfg_node_t *node;
} cfg_t;

static const pb_cfg_field_t FIELDS[] = {
    { "d", PB_CFG_DOUBLE, offsetof(cfg_t, d), 0, 0 },   { "i", PB_CFG_INT, offsetof(cfg_t, i), 0, 0 },
    { "b", PB_CFG_BOOL, offsetof(cfg_t, b), 0, 0 },     { "s", PB_CFG_STRING, offsetof(cfg_t, s), 8, 0 },
    { "v", PB_CFG_DOUBLES, offsetof(cfg_t, v), 3, 0 },  { "n", PB_CFG_NODE, offsetof(cfg_t, node), 0, 0 },
    PB_CFG_END,
};

/* Walks a tree, touching every scalar, as readers of routes and scenarios do. */
static void walk(const pb_cfg_node_t *n, int depth)
{
    if (!n || depth > 64) return;
    double d;
    pb_err_t err;
    if (pb_node_kind(n) == PB_NODE_SCALAR) {
        pb_node_double(n, "x", &d, &err);
        if (strlen(pb_node_str(n)) > 1 << 20) abort();
        return;
    }
    for (int i = 0; i < pb_node_count(n); i++) {
        if (pb_node_kind(n) == PB_NODE_MAP && !pb_node_key(n, i)) abort();
        walk(pb_node_at(n, i), depth + 1);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char path[64];
    if (!path[0]) snprintf(path, sizeof path, "/dev/shm/pb_fuzz_cfg_%d.yaml", (int)getpid());
    FILE *f = fopen(path, "wb");
    if (!f) return 0;
    fwrite(data, 1, size, f);
    fclose(f);
    pb_err_t err;
    pb_cfg_t *cfg = pb_cfg_load(path, &err);
    if (!cfg) {
        if (!strstr(err.msg, path)) abort();   /* every error names the file */
        return 0;
    }
    walk(pb_cfg_root(cfg), 0);
    cfg_t c = { 0 };
    if (pb_cfg_read(pb_cfg_root(cfg), FIELDS, &c, &err) != 0 && !strstr(err.msg, path)) abort();
    pb_cfg_free(cfg);
    return 0;
}
