#include "pb_signal.h"

#include <signal.h>
#include <string.h>
#include <unistd.h>

static volatile sig_atomic_t stop_count;

static void on_signal(int sig)
{
    (void)sig;
    if (++stop_count > 1) _exit(130);   /* second Ctrl-C: the user means it */
}

void pb_signal_install(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
}

int pb_signal_stop_requested(void) { return stop_count > 0; }
