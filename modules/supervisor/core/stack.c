/* Stack files: strict schema through pb_config, ${VAR} expansion, policy defaults. */
#include "stack.h"

#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pb_config.h"

void sv_policy_default(sv_policy_t *p)
{
    *p = (sv_policy_t){
        .restart = SV_RESTART_ALWAYS, .ready = SV_READY_STATUS, .heartbeat_s = 3, .start_grace_s = 15,
        .stop_timeout_s = 3, .backoff_initial_s = 0.1, .backoff_max_s = 30, .stable_s = 10, .max_failures = 5,
    };
}

int sv_expand(const char *src, sv_lookup_fn lookup, void *user, char *dst, size_t cap, pb_err_t *err)
{
    size_t n = 0;
    for (const char *s = src; *s;) {
        const char *val = NULL;
        char tmp[SV_PATH_MAX];
        if (s[0] == '$' && s[1] == '{') {
            const char *end = strchr(s, '}');
            if (!end) return pb_err_set(err, "'%s': '${' without a closing '}'", src);
            char name[SV_NAME_MAX * 2];
            size_t len = (size_t)(end - s - 2);
            if (len == 0 || len >= sizeof name) return pb_err_set(err, "'%s': bad variable name", src);
            memcpy(name, s + 2, len);
            name[len] = 0;
            char *dflt = strstr(name, ":-");
            if (dflt) { *dflt = 0; dflt += 2; }
            val = lookup ? lookup(name, user) : NULL;
            if (!val || (!*val && dflt)) {
                if (!dflt) return pb_err_set(err, "unset variable %s (give it with --set %s=VALUE or in the environment)", name, name);
                /* A default may itself name variables. */
                if (sv_expand(dflt, lookup, user, tmp, sizeof tmp, err)) return -1;
                val = tmp;
            }
            s = end + 1;
        } else {
            tmp[0] = *s++;
            tmp[1] = 0;
            val = tmp;
        }
        size_t l = strlen(val);
        if (n + l + 1 > cap) return pb_err_set(err, "'%s': longer than %zu bytes once expanded", src, cap - 1);
        memcpy(dst + n, val, l);
        n += l;
    }
    dst[n] = 0;
    return 0;
}

/* Every per-command key; `defaults:` takes the same ones except name, run, env. */
typedef struct {
    char name[SV_NAME_MAX];
    const pb_cfg_node_t *run, *env;
    char restart[16], ready[16];
    double heartbeat_s, start_grace_s, stop_timeout_s, backoff_initial_s, backoff_max_s, stable_s;
    long max_failures, nice;
} raw_cmd_t;

#define POLICY_FIELDS \
    { "restart", PB_CFG_STRING, offsetof(raw_cmd_t, restart), 16, 0 }, \
    { "ready", PB_CFG_STRING, offsetof(raw_cmd_t, ready), 16, 0 }, \
    { "heartbeat_s", PB_CFG_DOUBLE, offsetof(raw_cmd_t, heartbeat_s), 0, 0 }, \
    { "start_grace_s", PB_CFG_DOUBLE, offsetof(raw_cmd_t, start_grace_s), 0, 0 }, \
    { "stop_timeout_s", PB_CFG_DOUBLE, offsetof(raw_cmd_t, stop_timeout_s), 0, 0 }, \
    { "backoff_initial_s", PB_CFG_DOUBLE, offsetof(raw_cmd_t, backoff_initial_s), 0, 0 }, \
    { "backoff_max_s", PB_CFG_DOUBLE, offsetof(raw_cmd_t, backoff_max_s), 0, 0 }, \
    { "stable_s", PB_CFG_DOUBLE, offsetof(raw_cmd_t, stable_s), 0, 0 }, \
    { "max_failures", PB_CFG_INT, offsetof(raw_cmd_t, max_failures), 0, 0 }, \
    { "nice", PB_CFG_INT, offsetof(raw_cmd_t, nice), 0, 0 }

static const pb_cfg_field_t default_fields[] = { POLICY_FIELDS, PB_CFG_END };
static const pb_cfg_field_t command_fields[] = {
    { "name", PB_CFG_STRING, offsetof(raw_cmd_t, name), SV_NAME_MAX, 1 },
    { "run", PB_CFG_NODE, offsetof(raw_cmd_t, run), 0, 1 },
    { "env", PB_CFG_NODE, offsetof(raw_cmd_t, env), 0, 0 },
    POLICY_FIELDS, PB_CFG_END,
};

typedef struct {
    char name[SV_NAME_MAX];
    const pb_cfg_node_t *commands;
} raw_group_t;

static const pb_cfg_field_t group_fields[] = {
    { "name", PB_CFG_STRING, offsetof(raw_group_t, name), SV_NAME_MAX, 1 },
    { "commands", PB_CFG_NODE, offsetof(raw_group_t, commands), 0, 1 },
    PB_CFG_END,
};

typedef struct {
    char name[SV_NAME_MAX], lcm_url[SV_PATH_MAX], workdir[SV_PATH_MAX], output_dir[SV_PATH_MAX];
    long output_max_bytes, output_keep;
    const pb_cfg_node_t *defaults, *groups;
} raw_stack_t;

static const pb_cfg_field_t stack_fields[] = {
    { "name", PB_CFG_STRING, offsetof(raw_stack_t, name), SV_NAME_MAX, 1 },
    { "lcm_url", PB_CFG_STRING, offsetof(raw_stack_t, lcm_url), SV_PATH_MAX, 0 },
    { "workdir", PB_CFG_STRING, offsetof(raw_stack_t, workdir), SV_PATH_MAX, 0 },
    { "output_dir", PB_CFG_STRING, offsetof(raw_stack_t, output_dir), SV_PATH_MAX, 0 },
    { "output_max_bytes", PB_CFG_INT, offsetof(raw_stack_t, output_max_bytes), 0, 0 },
    { "output_keep", PB_CFG_INT, offsetof(raw_stack_t, output_keep), 0, 0 },
    { "defaults", PB_CFG_NODE, offsetof(raw_stack_t, defaults), 0, 0 },
    { "groups", PB_CFG_NODE, offsetof(raw_stack_t, groups), 0, 1 },
    PB_CFG_END,
};

static int where(pb_err_t *err, const pb_cfg_node_t *n, const char *fmt, const char *a, const char *b)
{
    char msg[600];
    snprintf(msg, sizeof msg, fmt, a, b);
    return pb_err_set(err, "%s:%d: %s", pb_node_file(n), pb_node_line(n), msg);
}

static int valid_name(const char *s)
{
    if (!*s) return 0;
    for (; *s; s++)
        if (!((*s >= 'a' && *s <= 'z') || (*s >= 'A' && *s <= 'Z') || (*s >= '0' && *s <= '9') || *s == '_' || *s == '-'))
            return 0;
    return 1;
}

static int expand_at(const pb_cfg_node_t *n, const char *src, sv_lookup_fn lk, void *u, char *dst, size_t cap, pb_err_t *err)
{
    if (sv_expand(src, lk, u, dst, cap, err) == 0) return 0;
    return pb_err_prefix(err, "%s:%d", pb_node_file(n), pb_node_line(n));
}

/* Policy strings to enums, ranges checked; n is the command (or defaults) node. */
static int to_policy(const raw_cmd_t *r, const pb_cfg_node_t *n, sv_policy_t *p, pb_err_t *err)
{
    if (!strcmp(r->restart, "always")) p->restart = SV_RESTART_ALWAYS;
    else if (!strcmp(r->restart, "on-failure")) p->restart = SV_RESTART_ON_FAILURE;
    else if (!strcmp(r->restart, "never")) p->restart = SV_RESTART_NEVER;
    else return where(err, n, "restart: expected always, on-failure or never, got '%s'%s", r->restart, "");
    if (!strcmp(r->ready, "status")) p->ready = SV_READY_STATUS;
    else if (!strcmp(r->ready, "started")) p->ready = SV_READY_STARTED;
    else return where(err, n, "ready: expected status or started, got '%s'%s", r->ready, "");
    struct { const char *key; double v, lo, hi; } num[] = {
        { "heartbeat_s", r->heartbeat_s, 0, 3600 }, { "start_grace_s", r->start_grace_s, 0, 3600 },
        { "stop_timeout_s", r->stop_timeout_s, 0.01, 600 }, { "backoff_initial_s", r->backoff_initial_s, 0, 3600 },
        { "backoff_max_s", r->backoff_max_s, 0, 86400 }, { "stable_s", r->stable_s, 0, 86400 },
        { "max_failures", (double)r->max_failures, 1, 1000 }, { "nice", (double)r->nice, 0, 19 },
    };
    for (size_t i = 0; i < sizeof num / sizeof num[0]; i++)
        if (!(num[i].v >= num[i].lo && num[i].v <= num[i].hi)) {
            char range[64];
            snprintf(range, sizeof range, "[%g, %g], got %g", num[i].lo, num[i].hi, num[i].v);
            return where(err, n, "%s: expected a number in %s", num[i].key, range);
        }
    if (r->backoff_max_s < r->backoff_initial_s) return where(err, n, "backoff_max_s is below backoff_initial_s%s%s", "", "");
    p->heartbeat_s = r->heartbeat_s; p->start_grace_s = r->start_grace_s; p->stop_timeout_s = r->stop_timeout_s;
    p->backoff_initial_s = r->backoff_initial_s; p->backoff_max_s = r->backoff_max_s; p->stable_s = r->stable_s;
    p->max_failures = r->max_failures;
    p->nice = r->nice;
    return 0;
}

static int read_command(const pb_cfg_node_t *n, const raw_cmd_t *dflt, sv_lookup_fn lk, void *u, sv_command_t *c, pb_err_t *err)
{
    raw_cmd_t r = *dflt;
    r.run = r.env = NULL;
    r.name[0] = 0;
    if (pb_cfg_read(n, command_fields, &r, err)) return -1;
    if (!valid_name(r.name)) return where(err, n, "name: '%s' is not a name (letters, digits, _ and -)%s", r.name, "");
    snprintf(c->name, sizeof c->name, "%s", r.name);
    c->line = pb_node_line(n);
    if (to_policy(&r, n, &c->policy, err)) return -1;
    if (pb_node_kind(r.run) != PB_NODE_LIST || pb_node_count(r.run) == 0)
        return where(err, r.run, "%s: run: expected a list [program, arg, ...]%s", c->name, "");
    if (pb_node_count(r.run) > SV_MAX_ARGS) return where(err, r.run, "%s: run: more than 64 arguments%s", c->name, "");
    for (int i = 0; i < pb_node_count(r.run); i++) {
        const pb_cfg_node_t *a = pb_node_at(r.run, i);
        if (!pb_node_str(a)) return where(err, a, "%s: run: item %s is not a value", c->name, i == 0 ? "0" : "> 0");
        char buf[SV_PATH_MAX * 2];
        if (expand_at(a, pb_node_str(a), lk, u, buf, sizeof buf, err)) return -1;
        c->argv[c->argc++] = strdup(buf);
    }
    c->argv[c->argc] = NULL;
    if (r.env) {
        if (pb_node_kind(r.env) != PB_NODE_MAP) return where(err, r.env, "%s: env: expected a mapping KEY: value%s", c->name, "");
        if (pb_node_count(r.env) > SV_MAX_ENV) return where(err, r.env, "%s: env: more than 32 variables%s", c->name, "");
        for (int i = 0; i < pb_node_count(r.env); i++) {
            const pb_cfg_node_t *v = pb_node_at(r.env, i);
            if (!pb_node_str(v)) return where(err, v, "%s: env: %s is not a value", c->name, pb_node_key(r.env, i));
            char buf[SV_PATH_MAX * 2];
            if (expand_at(v, pb_node_str(v), lk, u, buf, sizeof buf, err)) return -1;
            size_t len = strlen(pb_node_key(r.env, i)) + strlen(buf) + 2;
            char *kv = malloc(len);
            snprintf(kv, len, "%s=%s", pb_node_key(r.env, i), buf);
            c->env[c->nenv++] = kv;
        }
    }
    return 0;
}

int sv_stack_load(const char *path, sv_lookup_fn lk, void *u, sv_stack_t *s, pb_err_t *err)
{
    memset(s, 0, sizeof *s);
    snprintf(s->path, sizeof s->path, "%s", path);
    pb_cfg_t *cfg = pb_cfg_load(path, err);
    if (!cfg) return -1;
    raw_stack_t r = { .output_max_bytes = 10 * 1024 * 1024, .output_keep = 5 };
    snprintf(r.output_dir, sizeof r.output_dir, "build/run/output");
    snprintf(r.workdir, sizeof r.workdir, ".");
    const pb_cfg_node_t *root = pb_cfg_root(cfg);
    sv_policy_t defp;
    sv_policy_default(&defp);
    raw_cmd_t dflt = { .heartbeat_s = defp.heartbeat_s, .start_grace_s = defp.start_grace_s,
                       .stop_timeout_s = defp.stop_timeout_s, .backoff_initial_s = defp.backoff_initial_s,
                       .backoff_max_s = defp.backoff_max_s, .stable_s = defp.stable_s, .max_failures = defp.max_failures,
                       .nice = defp.nice };
    snprintf(dflt.restart, sizeof dflt.restart, "always");
    snprintf(dflt.ready, sizeof dflt.ready, "status");
    int rc = -1;
    if (pb_cfg_read(root, stack_fields, &r, err)) goto out;
    if (!valid_name(r.name)) { where(err, root, "name: '%s' is not a name (letters, digits, _ and -)%s", r.name, ""); goto out; }
    snprintf(s->name, sizeof s->name, "%s", r.name);
    if (expand_at(root, r.lcm_url, lk, u, s->lcm_url, sizeof s->lcm_url, err)) goto out;
    if (expand_at(root, r.output_dir, lk, u, s->output_dir, sizeof s->output_dir, err)) goto out;
    /* workdir is relative to the stack file's folder. */
    char wd[SV_PATH_MAX];
    if (expand_at(root, r.workdir, lk, u, wd, sizeof wd, err)) goto out;
    if (wd[0] == '/') snprintf(s->workdir, sizeof s->workdir, "%s", wd);
    else {
        char dir[SV_PATH_MAX];
        snprintf(dir, sizeof dir, "%s", path);
        char *slash = strrchr(dir, '/');
        if (slash) *slash = 0; else snprintf(dir, sizeof dir, ".");
        if (snprintf(s->workdir, sizeof s->workdir, "%s/%s", dir, wd) >= (int)sizeof s->workdir) {
            where(err, root, "workdir: path too long%s%s", "", "");
            goto out;
        }
    }
    if (r.output_max_bytes < 4096 || r.output_keep < 0 || r.output_keep > 100) {
        where(err, root, "output_max_bytes must be >= 4096 and output_keep in [0, 100]%s%s", "", "");
        goto out;
    }
    s->output_max_bytes = r.output_max_bytes;
    s->output_keep = r.output_keep;
    if (r.defaults) {
        if (pb_cfg_read(r.defaults, default_fields, &dflt, err)) goto out;
        sv_policy_t chk;
        if (to_policy(&dflt, r.defaults, &chk, err)) goto out;
    }
    if (pb_node_kind(r.groups) != PB_NODE_LIST || pb_node_count(r.groups) == 0) {
        where(err, r.groups, "groups: expected a list of {name, commands}%s%s", "", "");
        goto out;
    }
    if (pb_node_count(r.groups) > 16) { where(err, r.groups, "groups: more than 16%s%s", "", ""); goto out; }
    int total = 0;
    for (int g = 0; g < pb_node_count(r.groups); g++) total += pb_node_count(pb_node_get(pb_node_at(r.groups, g), "commands"));
    s->commands = calloc(total + 1, sizeof *s->commands);
    for (int g = 0; g < pb_node_count(r.groups); g++) {
        const pb_cfg_node_t *gn = pb_node_at(r.groups, g);
        raw_group_t rg = { .commands = NULL };
        if (pb_cfg_read(gn, group_fields, &rg, err)) goto out;
        if (!valid_name(rg.name)) { where(err, gn, "name: '%s' is not a name%s", rg.name, ""); goto out; }
        for (int k = 0; k < s->ngroups; k++)
            if (!strcmp(s->groups[k], rg.name)) { where(err, gn, "group '%s' is defined twice%s", rg.name, ""); goto out; }
        snprintf(s->groups[s->ngroups++], SV_NAME_MAX, "%s", rg.name);
        if (pb_node_kind(rg.commands) != PB_NODE_LIST || pb_node_count(rg.commands) == 0) {
            where(err, rg.commands, "%s: commands: expected a list of commands%s", rg.name, "");
            goto out;
        }
        for (int i = 0; i < pb_node_count(rg.commands); i++) {
            const pb_cfg_node_t *cn = pb_node_at(rg.commands, i);
            sv_command_t *c = &s->commands[s->ncommands];
            snprintf(c->group, sizeof c->group, "%s", rg.name);
            c->group_index = g;
            s->ncommands++;     /* counted first so sv_stack_free frees a half-read command */
            if (read_command(cn, &dflt, lk, u, c, err)) goto out;
            if (sv_stack_find(s, c->name) != s->ncommands - 1) {
                where(err, cn, "command name '%s' is used twice%s", c->name, "");
                goto out;
            }
        }
    }
    rc = 0;
out:
    pb_cfg_free(cfg);
    if (rc) sv_stack_free(s);
    return rc;
}

void sv_stack_free(sv_stack_t *s)
{
    for (int i = 0; i < s->ncommands; i++) {
        for (int k = 0; k < s->commands[i].argc; k++) free(s->commands[i].argv[k]);
        for (int k = 0; k < s->commands[i].nenv; k++) free(s->commands[i].env[k]);
    }
    free(s->commands);
    s->commands = NULL;
    s->ncommands = 0;
}

int sv_stack_find(const sv_stack_t *s, const char *name)
{
    for (int i = 0; i < s->ncommands; i++)
        if (!strcmp(s->commands[i].name, name)) return i;
    return -1;
}

int sv_stack_find_group(const sv_stack_t *s, const char *name)
{
    for (int g = 0; g < s->ngroups; g++)
        if (!strcmp(s->groups[g], name)) return g;
    return -1;
}
