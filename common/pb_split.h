/* pb_split: independent work run on two threads.
 *
 * pb_both(a, b) calls a() on this thread and b() on another, and returns when both are
 * done (when a throws, after b is done too); both on this thread when no thread can
 * start. a and b must not write what the other reads or writes, so the result is the same
 * as a(); b(): running them at once never changes an answer, only the wall time.
 *
 * pb_split2(n, fn) is pb_both for a loop over n independent items: fn(0, n / 2) here and
 * fn(n / 2, n) on another thread. Below `min_items` it is not worth a thread: fn(0, n).
 *
 * pb_take2(n, fn) calls fn(i) for every i < n, each item taken by whichever of the two
 * threads comes for the next one: for items of unequal cost (put the largest first), which
 * a split in halves would leave one thread waiting for the other. */
#ifndef PB_SPLIT_H
#define PB_SPLIT_H

#include <atomic>
#include <cstddef>
#include <future>
#include <system_error>

template <class A, class B>
void pb_both(A a, B b)
{
    std::future<void> other;   /* std::async's future waits for b when it is destroyed */
    try {
        other = std::async(std::launch::async, b);
    } catch (const std::system_error &) {
        b();
    }
    a();
    if (other.valid()) other.get();
}

template <class F>
void pb_split2(size_t n, F fn, size_t min_items = 4096)
{
    if (n < min_items) { fn((size_t)0, n); return; }
    pb_both([&fn, n]() { fn((size_t)0, n / 2); }, [&fn, n]() { fn(n / 2, n); });
}

template <class F>
void pb_take2(size_t n, F fn)
{
    std::atomic<size_t> next(0);
    auto run = [&]() {
        for (size_t i; (i = next.fetch_add(1)) < n;) fn(i);
    };
    if (n < 2) run();
    else pb_both(run, run);
}

#endif
