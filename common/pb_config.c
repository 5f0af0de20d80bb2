/* YAML config files read with libyaml into a tree that remembers lines, then
 * taken through schemas that refuse unknown keys and wrong types. */
#include "pb_config.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <yaml.h>

struct pb_cfg_node {
    pb_node_kind_t kind;
    int line;
    int quoted;             /* scalar written in quotes: a string, never a number */
    char *str;              /* scalar text */
    int n, cap;
    char **keys;            /* maps */
    pb_cfg_node_t **items;  /* map values or list items */
    const pb_cfg_t *doc;
};

struct pb_cfg {
    char *path;
    pb_cfg_node_t *root;
};

static void node_free(pb_cfg_node_t *n)
{
    if (!n) return;
    for (int i = 0; i < n->n; i++) {
        if (n->keys) free(n->keys[i]);
        node_free(n->items[i]);
    }
    free(n->keys);
    free(n->items);
    free(n->str);
    free(n);
}

void pb_cfg_free(pb_cfg_t *cfg)
{
    if (!cfg) return;
    node_free(cfg->root);
    free(cfg->path);
    free(cfg);
}

static pb_cfg_node_t *node_new(pb_cfg_t *doc, pb_node_kind_t kind, int line)
{
    pb_cfg_node_t *n = calloc(1, sizeof *n);
    n->kind = kind;
    n->line = line;
    n->doc = doc;
    return n;
}

static void node_append(pb_cfg_node_t *parent, char *key, pb_cfg_node_t *child)
{
    if (parent->n == parent->cap) {
        parent->cap = parent->cap ? 2 * parent->cap : 8;
        parent->items = realloc(parent->items, parent->cap * sizeof *parent->items);
        if (parent->kind == PB_NODE_MAP) parent->keys = realloc(parent->keys, parent->cap * sizeof *parent->keys);
    }
    if (parent->kind == PB_NODE_MAP) parent->keys[parent->n] = key;
    parent->items[parent->n++] = child;
}

/* Recursive descent over libyaml's event stream. */
static pb_cfg_node_t *parse_node(pb_cfg_t *doc, yaml_parser_t *p, yaml_event_t *ev, pb_err_t *err)
{
    int line = (int)ev->start_mark.line + 1;
    switch (ev->type) {
    case YAML_SCALAR_EVENT: {
        pb_cfg_node_t *n = node_new(doc, PB_NODE_SCALAR, line);
        n->str = strndup((const char *)ev->data.scalar.value, ev->data.scalar.length);
        n->quoted = ev->data.scalar.style == YAML_SINGLE_QUOTED_SCALAR_STYLE ||
                    ev->data.scalar.style == YAML_DOUBLE_QUOTED_SCALAR_STYLE;
        return n;
    }
    case YAML_ALIAS_EVENT:
        pb_err_set(err, "%s:%d: YAML aliases (*name) are not supported here", doc->path, line);
        return NULL;
    case YAML_SEQUENCE_START_EVENT:
    case YAML_MAPPING_START_EVENT: {
        int is_map = ev->type == YAML_MAPPING_START_EVENT;
        pb_cfg_node_t *n = node_new(doc, is_map ? PB_NODE_MAP : PB_NODE_LIST, line);
        for (;;) {
            yaml_event_t e;
            if (!yaml_parser_parse(p, &e)) {
                pb_err_set(err, "%s:%zu: YAML syntax error: %s", doc->path, p->problem_mark.line + 1,
                           p->problem ? p->problem : "unknown");
                node_free(n);
                return NULL;
            }
            if (e.type == YAML_SEQUENCE_END_EVENT || e.type == YAML_MAPPING_END_EVENT) {
                yaml_event_delete(&e);
                return n;
            }
            char *key = NULL;
            if (is_map) {
                if (e.type != YAML_SCALAR_EVENT) {
                    pb_err_set(err, "%s:%zu: mapping keys must be plain names", doc->path, e.start_mark.line + 1);
                    yaml_event_delete(&e);
                    node_free(n);
                    return NULL;
                }
                key = strndup((const char *)e.data.scalar.value, e.data.scalar.length);
                int kline = (int)e.start_mark.line + 1;
                yaml_event_delete(&e);
                if (pb_node_get(n, key)) {
                    pb_err_set(err, "%s:%d: duplicate key '%s'", doc->path, kline, key);
                    free(key);
                    node_free(n);
                    return NULL;
                }
                if (!yaml_parser_parse(p, &e)) {
                    pb_err_set(err, "%s:%zu: YAML syntax error: %s", doc->path, p->problem_mark.line + 1,
                               p->problem ? p->problem : "unknown");
                    free(key);
                    node_free(n);
                    return NULL;
                }
            }
            pb_cfg_node_t *child = parse_node(doc, p, &e, err);
            yaml_event_delete(&e);
            if (!child) { free(key); node_free(n); return NULL; }
            node_append(n, key, child);
        }
    }
    default:
        pb_err_set(err, "%s:%d: unexpected YAML event", doc->path, line);
        return NULL;
    }
}

pb_cfg_t *pb_cfg_load(const char *path, pb_err_t *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) { pb_err_set(err, "%s: cannot open: %s", path, strerror(errno)); return NULL; }
    pb_cfg_t *doc = calloc(1, sizeof *doc);
    doc->path = strdup(path);
    yaml_parser_t p;
    yaml_parser_initialize(&p);
    yaml_parser_set_input_file(&p, f);
    int ok = 0;
    for (;;) {
        yaml_event_t e;
        if (!yaml_parser_parse(&p, &e)) {
            pb_err_set(err, "%s:%zu: YAML syntax error: %s", path, p.problem_mark.line + 1, p.problem ? p.problem : "unknown");
            break;
        }
        yaml_event_type_t t = e.type;
        if (t == YAML_STREAM_END_EVENT) { yaml_event_delete(&e); ok = doc->root != NULL; if (!ok) pb_err_set(err, "%s: empty file", path); break; }
        if (t == YAML_STREAM_START_EVENT || t == YAML_DOCUMENT_START_EVENT || t == YAML_DOCUMENT_END_EVENT) {
            yaml_event_delete(&e);
            continue;
        }
        if (doc->root) {
            pb_err_set(err, "%s:%zu: more than one YAML document", path, e.start_mark.line + 1);
            yaml_event_delete(&e);
            break;
        }
        doc->root = parse_node(doc, &p, &e, err);
        yaml_event_delete(&e);
        if (!doc->root) break;
    }
    yaml_parser_delete(&p);
    fclose(f);
    if (!ok) { pb_cfg_free(doc); return NULL; }
    if (doc->root->kind != PB_NODE_MAP) {
        pb_err_set(err, "%s:%d: expected a mapping of keys at the top level", path, doc->root->line);
        pb_cfg_free(doc);
        return NULL;
    }
    return doc;
}

const pb_cfg_node_t *pb_cfg_root(const pb_cfg_t *cfg) { return cfg->root; }
const char *pb_cfg_path(const pb_cfg_t *cfg) { return cfg->path; }
pb_node_kind_t pb_node_kind(const pb_cfg_node_t *n) { return n->kind; }
int pb_node_line(const pb_cfg_node_t *n) { return n->line; }
const char *pb_node_file(const pb_cfg_node_t *n) { return n->doc->path; }
const char *pb_node_str(const pb_cfg_node_t *n) { return n && n->kind == PB_NODE_SCALAR ? n->str : NULL; }
int pb_node_count(const pb_cfg_node_t *n) { return n && n->kind != PB_NODE_SCALAR ? n->n : 0; }

const pb_cfg_node_t *pb_node_at(const pb_cfg_node_t *n, int i)
{
    return n && n->kind != PB_NODE_SCALAR && i >= 0 && i < n->n ? n->items[i] : NULL;
}

const char *pb_node_key(const pb_cfg_node_t *n, int i)
{
    return n && n->kind == PB_NODE_MAP && i >= 0 && i < n->n ? n->keys[i] : NULL;
}

const pb_cfg_node_t *pb_node_get(const pb_cfg_node_t *n, const char *key)
{
    if (!n || n->kind != PB_NODE_MAP) return NULL;
    for (int i = 0; i < n->n; i++)
        if (strcmp(n->keys[i], key) == 0) return n->items[i];
    return NULL;
}

static const char *kind_name(pb_node_kind_t k) { return k == PB_NODE_MAP ? "a mapping" : k == PB_NODE_LIST ? "a list" : "a value"; }

int pb_node_double(const pb_cfg_node_t *n, const char *what, double *out, pb_err_t *err)
{
    if (n->kind != PB_NODE_SCALAR)
        return pb_err_set(err, "%s:%d: %s: expected a number, got %s", pb_node_file(n), n->line, what, kind_name(n->kind));
    char *end;
    errno = 0;
    double v = strtod(n->str, &end);
    if (n->quoted || end == n->str || *end || errno == ERANGE || !isfinite(v))
        return pb_err_set(err, "%s:%d: %s: expected a number, got '%s'", pb_node_file(n), n->line, what, n->str);
    *out = v;
    return 0;
}

int pb_node_int(const pb_cfg_node_t *n, const char *what, long *out, pb_err_t *err)
{
    if (n->kind != PB_NODE_SCALAR)
        return pb_err_set(err, "%s:%d: %s: expected an integer, got %s", pb_node_file(n), n->line, what, kind_name(n->kind));
    char *end;
    errno = 0;
    long v = strtol(n->str, &end, 10);
    if (n->quoted || end == n->str || *end || errno == ERANGE)
        return pb_err_set(err, "%s:%d: %s: expected an integer, got '%s'", pb_node_file(n), n->line, what, n->str);
    *out = v;
    return 0;
}

int pb_node_bool(const pb_cfg_node_t *n, const char *what, int *out, pb_err_t *err)
{
    if (n->kind == PB_NODE_SCALAR && !n->quoted) {
        if (!strcasecmp(n->str, "true") || !strcasecmp(n->str, "yes") || !strcasecmp(n->str, "on")) { *out = 1; return 0; }
        if (!strcasecmp(n->str, "false") || !strcasecmp(n->str, "no") || !strcasecmp(n->str, "off")) { *out = 0; return 0; }
    }
    return pb_err_set(err, "%s:%d: %s: expected true or false, got %s%s%s", pb_node_file(n), n->line, what,
                      n->kind == PB_NODE_SCALAR ? "'" : "", n->kind == PB_NODE_SCALAR ? n->str : kind_name(n->kind),
                      n->kind == PB_NODE_SCALAR ? "'" : "");
}

int pb_node_doubles(const pb_cfg_node_t *n, const char *what, double *out, int len, pb_err_t *err)
{
    if (n->kind != PB_NODE_LIST || n->n != len)
        return pb_err_set(err, "%s:%d: %s: expected a list of %d numbers", pb_node_file(n), n->line, what, len);
    for (int i = 0; i < len; i++)
        if (pb_node_double(n->items[i], what, &out[i], err) != 0) return -1;
    return 0;
}

int pb_cfg_read(const pb_cfg_node_t *map, const pb_cfg_field_t *fields, void *out, pb_err_t *err)
{
    if (!map || map->kind != PB_NODE_MAP)
        return pb_err_set(err, "%s:%d: expected a mapping of keys", map ? pb_node_file(map) : "?", map ? map->line : 0);
    for (int i = 0; i < map->n; i++) {
        const pb_cfg_field_t *f = fields;
        while (f->key && strcmp(f->key, map->keys[i]) != 0) f++;
        if (!f->key) {
            char known[512] = "";
            size_t used = 0;
            for (const pb_cfg_field_t *g = fields; g->key && used < sizeof known - 64; g++)
                used += snprintf(known + used, sizeof known - used, "%s%s", used ? ", " : "", g->key);
            return pb_err_set(err, "%s:%d: unknown key '%s' (expected one of: %s)", pb_node_file(map),
                              map->items[i]->line, map->keys[i], known);
        }
        const pb_cfg_node_t *v = map->items[i];
        char *dst = (char *)out + f->offset;
        int rc = 0;
        switch (f->type) {
        case PB_CFG_DOUBLE: rc = pb_node_double(v, f->key, (double *)dst, err); break;
        case PB_CFG_INT: rc = pb_node_int(v, f->key, (long *)dst, err); break;
        case PB_CFG_BOOL: rc = pb_node_bool(v, f->key, (int *)dst, err); break;
        case PB_CFG_DOUBLES: rc = pb_node_doubles(v, f->key, (double *)dst, f->len, err); break;
        case PB_CFG_STRING:
            if (v->kind != PB_NODE_SCALAR)
                rc = pb_err_set(err, "%s:%d: %s: expected a string, got %s", pb_node_file(v), v->line, f->key, kind_name(v->kind));
            else if ((int)strlen(v->str) >= f->len)
                rc = pb_err_set(err, "%s:%d: %s: longer than %d characters", pb_node_file(v), v->line, f->key, f->len - 1);
            else
                strcpy(dst, v->str);
            break;
        case PB_CFG_NODE:
            if (v->kind == PB_NODE_SCALAR)
                rc = pb_err_set(err, "%s:%d: %s: expected a mapping or a list, got '%s'", pb_node_file(v), v->line, f->key, v->str);
            else
                *(const pb_cfg_node_t **)dst = v;
            break;
        }
        if (rc) return -1;
    }
    for (const pb_cfg_field_t *f = fields; f->key; f++)
        if (f->required && !pb_node_get(map, f->key))
            return pb_err_set(err, "%s:%d: missing required key '%s'", pb_node_file(map), map->line, f->key);
    return 0;
}
