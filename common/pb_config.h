/* pb_config: the one config format (YAML, read with libyaml) for vehicle, site,
 * route and supervisor files.
 *
 * A file is loaded into a tree of nodes that remember their line. Readers then
 * take values through a schema (pb_cfg_read) that refuses unknown keys, missing
 * required keys and wrong types with "FILE:LINE: ..." so that nothing starts
 * half-configured.
 *
 * Ownership: pb_cfg_load returns a document the caller frees with pb_cfg_free;
 * nodes and strings inside it live as long as the document. */
#ifndef PB_CONFIG_H
#define PB_CONFIG_H

#include <stddef.h>
#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pb_cfg pb_cfg_t;
typedef struct pb_cfg_node pb_cfg_node_t;

typedef enum { PB_NODE_SCALAR, PB_NODE_MAP, PB_NODE_LIST } pb_node_kind_t;

pb_cfg_t *pb_cfg_load(const char *path, pb_err_t *err);
void pb_cfg_free(pb_cfg_t *cfg);
const pb_cfg_node_t *pb_cfg_root(const pb_cfg_t *cfg);
const char *pb_cfg_path(const pb_cfg_t *cfg);

pb_node_kind_t pb_node_kind(const pb_cfg_node_t *n);
int pb_node_line(const pb_cfg_node_t *n);
const char *pb_node_file(const pb_cfg_node_t *n);
/* Scalars */
const char *pb_node_str(const pb_cfg_node_t *n);            /* NULL unless scalar */
/* Maps */
const pb_cfg_node_t *pb_node_get(const pb_cfg_node_t *map, const char *key); /* NULL if absent */
/* Lists and maps: number of items, and item i (for maps: the value; key via pb_node_key) */
int pb_node_count(const pb_cfg_node_t *n);
const pb_cfg_node_t *pb_node_at(const pb_cfg_node_t *n, int i);
const char *pb_node_key(const pb_cfg_node_t *map, int i);

/* Typed scalar conversion; -1 with "FILE:LINE: KEY: expected a number, got 'x'". */
int pb_node_double(const pb_cfg_node_t *n, const char *what, double *out, pb_err_t *err);
int pb_node_int(const pb_cfg_node_t *n, const char *what, long *out, pb_err_t *err);
int pb_node_bool(const pb_cfg_node_t *n, const char *what, int *out, pb_err_t *err);
/* A list of exactly len numbers ([x, y, z]). */
int pb_node_doubles(const pb_cfg_node_t *n, const char *what, double *out, int len, pb_err_t *err);

/* Schema-checked reading of one mapping into a struct. */
typedef enum {
    PB_CFG_DOUBLE,      /* double */
    PB_CFG_INT,         /* long */
    PB_CFG_BOOL,        /* int 0/1 */
    PB_CFG_STRING,      /* char[len] (len = buffer size) */
    PB_CFG_DOUBLES,     /* double[len], a YAML list of exactly len numbers */
    PB_CFG_NODE,        /* const pb_cfg_node_t * (a map or list the caller reads itself) */
} pb_cfg_type_t;

typedef struct {
    const char *key;
    pb_cfg_type_t type;
    size_t offset;      /* offsetof(struct, field) */
    int len;            /* PB_CFG_STRING: buffer size; PB_CFG_DOUBLES: element count */
    int required;
} pb_cfg_field_t;

#define PB_CFG_END { NULL, 0, 0, 0, 0 }

/* Reads every key of map through fields (terminated by PB_CFG_END) into out.
 * Refuses a key not in fields, a missing required key, or a value of the wrong
 * type, with file and line. Fields absent and not required keep out's value
 * (the caller's defaults). Returns 0 or -1. */
int pb_cfg_read(const pb_cfg_node_t *map, const pb_cfg_field_t *fields, void *out, pb_err_t *err);

#ifdef __cplusplus
}
#endif
#endif
