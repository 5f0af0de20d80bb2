/* libFuzzer target: the YAML config loader and schema reader on arbitrary bytes.
 * fuzz-sources: common/pb_config.c common/pb_err.c */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../c/cfg_thing.h"
#include "fuzz_common.h"
#include "pb_config.h"

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
    const char *path = fuzz_input_file("cfg", ".yaml", data, size);
    if (!path) return 0;
    pb_err_t err;
    pb_cfg_t *cfg = pb_cfg_load(path, &err);
    if (!cfg) {
        if (!strstr(err.msg, path)) abort();   /* every error names the file */
        return 0;
    }
    walk(pb_cfg_root(cfg), 0);
    thing_t c = { 0 };
    if (pb_cfg_read(pb_cfg_root(cfg), THING, &c, &err) != 0 && !strstr(err.msg, path)) abort();
    pb_cfg_free(cfg);
    return 0;
}
