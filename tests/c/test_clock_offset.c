/* pb_clock_offset: a device's clock against the sensors' from its messages' lags. */
#include "pb_check.h"
#include "pb_clock_offset.h"

/* The rule on a drive's lags: within 0.3 s of 0 no offset; beyond, the median, which a stray
 * lag (a message held up in a buffer) does not move. */
static void test_median(void)
{
    CHECK(pb_clock_offset_median(NULL, 0, 300000) == 0);
    int64_t agree[] = { 20000, 80000, -90000, 250000, 60000 };
    CHECK(pb_clock_offset_median(agree, 5, 300000) == 0);
    int64_t gps[100];   /* a receiver on GPS time against sensors on UTC, and one stray lag */
    for (int i = 0; i < 99; i++) gps[i] = 18000000 + (i % 10) * 10000;
    gps[99] = -5000000;
    CHECK(pb_clock_offset_median(gps, 100, 300000) == 18040000);
    int64_t behind[] = { -2100000, -2050000, -1990000 };
    CHECK(pb_clock_offset_median(behind, 3, 300000) == -2050000);
    int64_t near[] = { 350000, 360000, 340000 };
    CHECK(pb_clock_offset_median(near, 3, 300000) == 350000);
    CHECK(pb_clock_offset_median(near, 3, 400000) == 0);
}

/* Live: an offset from the third message on, reported once, again when it goes away; no lag
 * before any sensor; forgetting the lags (the sensors' clock stepped) keeps the offset until
 * new lags say otherwise. */
static void test_live(void)
{
    pb_clock_offset_t c;
    pb_clock_offset_init(&c, 300000);
    CHECK(pb_clock_offset_add(&c, 5000000, 0) == 0 && c.n == 0);   /* no sensor time yet */
    int64_t t = 10000000;
    CHECK(pb_clock_offset_add(&c, t + 2000000, t) == 0 && c.offset == 0);
    CHECK(pb_clock_offset_add(&c, t + 2100000, t + 100000) == 0 && c.offset == 0);   /* two lags: not yet */
    CHECK(pb_clock_offset_add(&c, t + 2200000, t + 150000) == 1 && c.offset == 2000000 && c.reported == 2000000);
    int reports = 0;
    for (int i = 3; i < 20; i++) reports += pb_clock_offset_add(&c, t + 2000000 + i * 100000, t + i * 100000 - 50000);
    CHECK(reports == 0 && c.offset == 2050000);   /* within tol of the one reported: not again */
    pb_clock_offset_forget(&c);
    CHECK(c.n == 0 && c.offset == 2050000);
    reports = 0;
    for (int i = 20; i < 25; i++) reports += pb_clock_offset_add(&c, t + i * 100000, t + i * 100000 - 50000);
    CHECK(reports == 1 && c.offset == 0 && c.reported == 0);   /* the clocks agree again: said once */
}

int main(void)
{
    test_median();
    test_live();
    return pb_check_report("test_clock_offset");
}
