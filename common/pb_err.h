/* pb_err: an error as a return code plus a message.
 *
 * Every function that can fail returns 0 (or a valid pointer) on success and
 * -1 (or NULL) on failure, and fills the caller's pb_err_t with one line that
 * names what and where: "maps/x/route.yaml:12: unknown key 'spede'",
 * "drive.lcm: byte 1048576: bad sync word". The caller owns the struct; a NULL
 * pb_err_t * is allowed and drops the message. */
#ifndef PB_ERR_H
#define PB_ERR_H

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    char msg[1024];
} pb_err_t;

/* Sets the message (printf format). Always returns -1, so `return pb_err_set(...)` works. */
int pb_err_set(pb_err_t *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Prefixes the existing message with "fmt: " (to add a file or a channel). Returns -1. */
int pb_err_prefix(pb_err_t *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#ifdef __cplusplus
}
#endif
#endif
