#include "pb_progress.h"

#include <stdio.h>
#include <unistd.h>

#include "pb_clock.h"

void pb_progress_start(pb_progress_t *p, const char *label, int64_t total, int quiet)
{
    p->label = label;
    p->total = total > 0 ? total : 1;
    p->done = 0;
    p->last_permille = -1;
    p->tty = isatty(2);
    p->quiet = quiet;
    p->t_start = pb_clock_monotonic_ms() * 1e-3;
}

static void draw(pb_progress_t *p, int final)
{
    int permille = (int)(1000 * p->done / p->total);
    if (permille > 1000) permille = 1000;
    double el = pb_clock_monotonic_ms() * 1e-3 - p->t_start;
    if (p->tty) {
        int width = 30, fill = permille * width / 1000;
        char bar[64];
        for (int i = 0; i < width; i++) bar[i] = i < fill ? '#' : '.';
        bar[width] = 0;
        double eta = permille > 0 ? el * (1000 - permille) / permille : 0;
        fprintf(stderr, "\r%-14s [%s] %5.1f%%  %5.1fs elapsed  %5.1fs left ", p->label, bar, permille / 10.0, el, eta);
        if (final) fputc('\n', stderr);
    } else if (final || permille / 100 != p->last_permille / 100) {
        fprintf(stderr, "%s: %3d%% (%.1fs)\n", p->label, permille / 10, el);
    }
    fflush(stderr);
    p->last_permille = permille;
}

void pb_progress_update(pb_progress_t *p, int64_t done)
{
    p->done = done;
    if (p->quiet) return;
    int permille = (int)(1000 * done / p->total);
    if (permille != p->last_permille && (p->tty || permille / 100 != p->last_permille / 100)) draw(p, 0);
}

void pb_progress_finish(pb_progress_t *p)
{
    if (p->quiet) return;
    p->done = p->total;
    draw(p, 1);
}
