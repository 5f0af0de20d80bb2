/* stack: a supervisor's stack file (YAML, read through pb_config's strict schema).
 *
 *   name: replay
 *   lcm_url: udpm://...            used when LCM_DEFAULT_URL is not set
 *   workdir: ..                    commands run here (relative to the stack file)
 *   output_dir: build/run/output   each command's stdout+stderr: NAME.log, rotated
 *   defaults: { restart: always, heartbeat_s: 2, ... }    any per-command key below
 *   groups:                        started in this order; a group starts when every
 *     - name: recorder             command of the groups before it is ready
 *       commands:
 *         - name: logger
 *           run: [.venv/bin/lcm-logger, ...]
 *           ready: started | status
 *           nice: 10                   lower CPU priority (0..19)
 *           env: { KEY: value }
 *
 * Strings may use ${VAR} and ${VAR:-default}, looked up through the caller's
 * function (the supervisor: --set NAME=VALUE, then the environment); an unset
 * variable without a default is an error naming file and line.
 * Ownership: sv_stack_load fills a caller-owned sv_stack_t; sv_stack_free frees
 * what it allocated. */
#ifndef SV_STACK_H
#define SV_STACK_H

#include <stddef.h>

#include "pb_err.h"

#define SV_NAME_MAX 64
#define SV_PATH_MAX 1024
#define SV_MAX_ARGS 64
#define SV_MAX_ENV 32

typedef enum { SV_RESTART_ALWAYS, SV_RESTART_ON_FAILURE, SV_RESTART_NEVER } sv_restart_t;
typedef enum { SV_READY_STARTED, SV_READY_STATUS } sv_ready_t;

/* How one command is kept running; every field has a default (stack `defaults:`). */
typedef struct {
    sv_restart_t restart;       /* always (default), on-failure (exit 0 is final), never */
    sv_ready_t ready;           /* status (default): ready at its first STATUS; started: at once */
    double heartbeat_s;         /* STATUS older than this is a hang (0: no heartbeat; default 3) */
    double start_grace_s;       /* no hang verdict this long after a start (default 15) */
    double stop_timeout_s;      /* SIGTERM, then SIGKILL to the group after this (default 3) */
    double backoff_initial_s;   /* first restart delay after a failure (default 0.1) */
    double backoff_max_s;       /* delays double up to this (default 30) */
    double stable_s;            /* a run this long resets the backoff (default 10) */
    long max_failures;          /* this many failures in a row -> FAILED (default 5) */
    long nice;                  /* scheduling niceness 0..19 of the process (default 0): what
                                 * may wait when the CPU is short, e.g. occlusion behind the localizer */
} sv_policy_t;

typedef struct {
    char name[SV_NAME_MAX];
    char group[SV_NAME_MAX];
    int group_index;
    int argc;
    char *argv[SV_MAX_ARGS + 1];    /* NULL-terminated */
    int nenv;
    char *env[SV_MAX_ENV];          /* "KEY=value" */
    sv_policy_t policy;
    int line;                       /* in the stack file */
} sv_command_t;

typedef struct {
    char name[SV_NAME_MAX];
    char path[SV_PATH_MAX];
    char lcm_url[SV_PATH_MAX];      /* "" if the file has none */
    char workdir[SV_PATH_MAX];      /* absolute or relative to the caller's cwd */
    char output_dir[SV_PATH_MAX];   /* relative to workdir unless absolute */
    long output_max_bytes;          /* rotate NAME.log past this (default 10 MB) */
    long output_keep;               /* rotated files kept: NAME.log.1 .. .N (default 5) */
    int ngroups;
    char groups[16][SV_NAME_MAX];
    int ncommands;
    sv_command_t *commands;
} sv_stack_t;

/* Returns the value of a variable or NULL if unset. */
typedef const char *(*sv_lookup_fn)(const char *name, void *user);

void sv_policy_default(sv_policy_t *p);
int sv_stack_load(const char *path, sv_lookup_fn lookup, void *user, sv_stack_t *out, pb_err_t *err);
void sv_stack_free(sv_stack_t *s);
/* Index of a command by name, or -1. */
int sv_stack_find(const sv_stack_t *s, const char *name);
/* Index of a group by name, or -1. */
int sv_stack_find_group(const sv_stack_t *s, const char *name);
/* Expands ${VAR} and ${VAR:-default} in src into dst; -1 with "unset variable VAR". */
int sv_expand(const char *src, sv_lookup_fn lookup, void *user, char *dst, size_t cap, pb_err_t *err);

#endif
