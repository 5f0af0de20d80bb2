/* pb_split: a loop over independent items run on two threads.
 *
 * pb_split2(n, fn) calls fn(0, n / 2) on this thread and fn(n / 2, n) on another, and
 * returns when both are done; both on this thread when no thread can start. fn must write
 * only what belongs to its own items, so the result is the same as fn(0, n) alone: a
 * split never changes an answer, only the wall time. Below `min_items` it is not worth
 * a thread: fn(0, n) here. */
#ifndef PB_SPLIT_H
#define PB_SPLIT_H

#include <cstddef>
#include <future>
#include <system_error>

template <class F>
void pb_split2(size_t n, F fn, size_t min_items = 4096)
{
    if (n < min_items) { fn((size_t)0, n); return; }
    std::future<void> second;
    try {
        second = std::async(std::launch::async, [&fn, n]() { fn(n / 2, n); });
    } catch (const std::system_error &) {
        fn(n / 2, n);
    }
    fn((size_t)0, n / 2);
    if (second.valid()) second.get();
}

#endif
