/* pb_opt: the option table parser every binary's main uses. */
#include <stdlib.h>
#include <unistd.h>

#include "pb_check.h"
#include "pb_opt.h"

static FILE *usage_to;   /* where usage() was last printed, or NULL */
static void usage(FILE *f) { usage_to = f; }

static char err_text[4096];   /* what the last parse printed on stderr */

/* Variables of the test program's options, reset before each parse. */
static const char *in, *out, *channel;
static long frames;
static int stride, quiet, ground_truth;
static bool verbose;
static double rate;
static int64_t age_us;
static int ndrops, mode;
static const char *const modes[] = { "auto", "on", "off" };
static const char *drops[4];

static int add_drop(const char *prog, const char *arg, void *var)
{
    int *n = var;
    if (*n == 4) { fprintf(stderr, "%s: --drop: at most 4\n", prog); return -1; }
    drops[(*n)++] = arg;
    return 0;
}

/* Parses the words (NULL-terminated) as the command line of "prog" with FLAGS; stderr
 * is caught in err_text. Returns what pb_opt_parse returned. */
static int parse(int flags, const char *words[])
{
    in = out = NULL;
    channel = "POSE";
    frames = 300;
    stride = 1;
    quiet = 0;
    ground_truth = 1;
    verbose = false;
    rate = 60;
    age_us = 0;
    ndrops = 0;
    mode = 0;
    usage_to = NULL;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("log", &in), PB_OPT_REQUIRED("out", &out), PB_OPT_STRING("channel", &channel),
        PB_OPT_LONG("frames", &frames, 3, 1000000), PB_OPT_INT("stride", &stride, 1, 16),
        PB_OPT_DOUBLE("rate", &rate, 30, 90), PB_OPT_FLAG("quiet", &quiet, 1),
        PB_OPT_FLAG("no-ground-truth", &ground_truth, 0), PB_OPT_BOOL("verbose", &verbose, 1),
        PB_OPT_CALL("drop", add_drop, &ndrops), PB_OPT_CHOICE("mode", &mode, modes, 3),
        PB_OPT_MICROS("age-ms", &age_us, 0, 1e6, 1000), PB_OPT_ENTRY("channel-short", 'c', PB_OPT_K_STRING, &channel, 0, 0, 0, 0, NULL),
        PB_OPT_END,
    };
    char *argv[32];
    int argc = 0;
    argv[argc++] = (char *)"prog";
    for (int i = 0; words[i]; i++) argv[argc++] = (char *)words[i];
    argv[argc] = NULL;

    char path[] = "/tmp/test_opt_XXXXXX";
    int fd = mkstemp(path);
    if (fd < 0) { perror("test_opt: mkstemp"); exit(1); }
    fflush(stderr);
    int saved = dup(2);
    dup2(fd, 2);
    int rc = pb_opt_parse("prog", opts, usage, flags, argc, argv);
    fflush(stderr);
    dup2(saved, 2);
    close(saved);
    ssize_t n = pread(fd, err_text, sizeof err_text - 1, 0);
    err_text[n > 0 ? n : 0] = 0;
    close(fd);
    unlink(path);
    return rc;
}

#define WORDS(...) ((const char *[]){ __VA_ARGS__, NULL })

int main(void)
{
    /* Every kind of option, in both spellings (--opt VALUE and --opt=VALUE). */
    CHECK(parse(0, WORDS("--log", "a.lcm", "--out=b.lcm", "--frames", "42", "--stride", "16", "--rate=30.5", "--quiet",
                         "--no-ground-truth", "--verbose", "--drop", "X", "--drop", "Y")) == -1);
    CHECK(in && !strcmp(in, "a.lcm") && out && !strcmp(out, "b.lcm"));
    CHECK(!strcmp(channel, "POSE"));   /* a default stays */
    CHECK(frames == 42 && stride == 16 && rate == 30.5 && quiet == 1 && ground_truth == 0 && verbose);
    CHECK(ndrops == 2 && !strcmp(drops[0], "X") && !strcmp(drops[1], "Y"));
    CHECK(err_text[0] == 0 && usage_to == NULL);
    /* the one-letter form of an entry that has one */
    CHECK(parse(0, WORDS("--log", "a", "--out", "b", "-c", "GT")) == -1 && !strcmp(channel, "GT"));

    /* --help and -h: usage on stdout, status 0, even with errors after it */
    CHECK(parse(0, WORDS("--help")) == 0 && usage_to == stdout);
    CHECK(parse(0, WORDS("-h", "--frames", "x")) == 0 && usage_to == stdout);

    /* Numbers out of range or not numbers: pb_arg's message, no usage, status 2. */
    CHECK(parse(0, WORDS("--log", "a", "--out", "b", "--frames", "2")) == 2 && usage_to == NULL);
    CHECK_CONTAINS(err_text, "prog: --frames: expected an integer in [3, 1000000], got '2'");
    CHECK(parse(0, WORDS("--stride", "17")) == 2);
    CHECK_CONTAINS(err_text, "prog: --stride: expected an integer in [1, 16], got '17'");
    CHECK(parse(0, WORDS("--rate", "60x")) == 2);
    CHECK_CONTAINS(err_text, "prog: --rate: expected a number in [30, 90], got '60x'");
    CHECK(parse(0, WORDS("--rate", "nan")) == 2);

    /* A duration: given in ms, kept in us; its range is in ms */
    CHECK(parse(0, WORDS("--log", "a", "--out", "b", "--age-ms", "2.5")) == -1 && age_us == 2500);
    CHECK(parse(0, WORDS("--age-ms", "-1")) == 2);
    CHECK_CONTAINS(err_text, "prog: --age-ms: expected a number in [0, 1e+06], got '-1'\n");

    /* A word of a list: its index; another word: the list in the message. */
    CHECK(parse(0, WORDS("--log", "a", "--out", "b", "--mode", "off")) == -1 && mode == 2);
    CHECK(parse(0, WORDS("--mode", "of")) == 2);
    CHECK_CONTAINS(err_text, "prog: --mode: expected auto, on or off, got 'of'\n");

    /* A function's refusal: its message, status 2. */
    CHECK(parse(0, WORDS("--drop", "1", "--drop", "2", "--drop", "3", "--drop", "4", "--drop", "5")) == 2);
    CHECK_CONTAINS(err_text, "prog: --drop: at most 4");

    /* Unknown options and missing values: getopt's message, usage on stderr, status 2. */
    CHECK(parse(0, WORDS("--nosuch")) == 2 && usage_to == stderr);
    CHECK_CONTAINS(err_text, "--nosuch");
    CHECK(parse(0, WORDS("--log")) == 2 && usage_to == stderr);
    CHECK(parse(0, WORDS("--quiet=1")) == 2 && usage_to == stderr);

    /* Required options: every required one named when any is missing. */
    CHECK(parse(0, WORDS("--log", "a")) == 2 && usage_to == stderr);
    CHECK_CONTAINS(err_text, "prog: --log and --out are required\n");
    CHECK(parse(0, WORDS("--quiet")) == 2);
    CHECK_CONTAINS(err_text, "prog: --log and --out are required\n");

    /* Words that are not options: refused unless the flags take them. */
    CHECK(parse(0, WORDS("--log", "a", "--out", "b", "stray")) == 2 && usage_to == stderr);
    CHECK_CONTAINS(err_text, "prog: unexpected argument 'stray'\n");
    CHECK(parse(PB_OPT_ARGS, WORDS("one", "--log", "a", "two", "--out", "b")) == -1);
    CHECK(optind == 5);   /* getopt moved the arguments to the end */
    /* in order: options end at the first argument; what follows is the program's */
    CHECK(parse(PB_OPT_IN_ORDER, WORDS("--log", "a", "--out", "b", "tail", "-n", "5")) == -1);
    CHECK(optind == 5 && quiet == 0);

    return pb_check_report("test_opt");
}
