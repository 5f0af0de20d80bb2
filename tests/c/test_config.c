/* pb_config: schema reading, and refusal of bad files with file:line. */
#include <stdlib.h>
#include <unistd.h>

#include "cfg_thing.h"
#include "pb_check.h"

static char dir[] = "/tmp/pb_test_config_XXXXXX";

/* Loads text and reads it through THING; returns rc and leaves the error in err. */
static int load(const char *text, thing_t *t, pb_err_t *err)
{
    const char *path = pb_check_write_file(dir, "c.yaml", text);
    pb_cfg_t *cfg = pb_cfg_load(path, err);
    if (!cfg) return -1;
    int rc = pb_cfg_read(pb_cfg_root(cfg), THING, t, err);
    pb_cfg_free(cfg);
    return rc;
}

int main(void)
{
    if (!mkdtemp(dir)) return 2;
    pb_err_t err;
    thing_t t = { .count = 7 };

    /* A good file: values land, defaults survive. */
    CHECK(load("# comment\nlength: 4.5\nenabled: yes\nname: prius\nxyz: [1, 2.5, -3]\nextra: {a: 1}\n", &t, &err) == 0);
    CHECK_NEAR(t.length, 4.5, 0);
    CHECK(t.count == 7);
    CHECK(t.enabled == 1);
    CHECK(strcmp(t.name, "prius") == 0);
    CHECK_NEAR(t.xyz[1], 2.5, 0);
    CHECK(t.extra != NULL);   /* node pointers die with the document; lines are checked below */

    /* Refusals: unknown key (named, with its line), wrong types, missing required key,
     * duplicate key, syntax error, non-mapping top level, empty file. */
    static const struct { const char *text, *want; } bad[] = {
        { "length: 1\nlenght: 2\n", "c.yaml:2: unknown key 'lenght'" },
        { "length: long\n", "c.yaml:1: length: expected a number, got 'long'" },
        { "length: 1\ncount: 2.5\n", "c.yaml:2: count: expected an integer" },
        { "length: \"3\"\n", "c.yaml:1: length: expected a number" },   /* a quoted number is a string */
        { "length: 1\nxyz: [1, 2]\n", "c.yaml:2: xyz: expected a list of 3 numbers" },
        { "length: 1\nenabled: maybe\n", "c.yaml:2: enabled: expected true or false" },
        { "length: [1]\n", "c.yaml:1: length: expected a number, got a list" },
        { "count: 1\n", "missing required key 'length'" },
        { "length: 1\nlength: 2\n", "c.yaml:2: duplicate key 'length'" },
        { "length: 1\nxyz: [1, 2\nname: x\n", "YAML syntax error" },
        { "- 1\n- 2\n", "c.yaml:1: expected a mapping" },
        { "", "empty file" },
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        CHECK_CASE(bad[i].want, load(bad[i].text, &t, &err) == -1);
        CHECK_CONTAINS(err.msg, bad[i].want);
    }
    CHECK(pb_cfg_load("/nonexistent/x.yaml", &err) == NULL);
    CHECK_CONTAINS(err.msg, "/nonexistent/x.yaml: cannot open");

    /* Tree access for lists of maps (routes, scenarios). */
    const char *path = pb_check_write_file(dir, "l.yaml", "points:\n  - {x: 1, y: 2}\n  - {x: 3, y: 4}\n");
    pb_cfg_t *cfg = pb_cfg_load(path, &err);
    CHECK(cfg != NULL);
    if (cfg) {
        const pb_cfg_node_t *pts = pb_node_get(pb_cfg_root(cfg), "points");
        CHECK(pb_node_count(pts) == 2);
        double y = 0;
        CHECK(pb_node_double(pb_node_get(pb_node_at(pts, 1), "y"), "y", &y, &err) == 0);
        CHECK_NEAR(y, 4, 0);
        CHECK(pb_node_line(pb_node_at(pts, 1)) == 3);
        pb_cfg_free(cfg);
    }
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0) return 2;
    return pb_check_report("test_config");
}
