/* pb_split.h: every item of pb_split2 and pb_take2 done once, on two threads at most. */
#include <atomic>
#include <mutex>
#include <set>
#include <thread>
#include <vector>
#include "pb_check.h"
#include "pb_split.h"

int main()
{
    for (size_t n : {0, 1, 2, 3, 1000, 100000}) {
        std::vector<std::atomic<int>> done(n);
        std::mutex mu;
        std::set<std::thread::id> threads;
        /* items of unequal cost, the largest first */
        pb_take2(n, [&](size_t i) {
            volatile double x = 0;
            for (size_t k = 0; k < (n - i) % 97; k++) x += (double)k;
            done[i]++;
            std::lock_guard<std::mutex> lk(mu);
            threads.insert(std::this_thread::get_id());
        });
        size_t once = 0;
        for (auto &d : done) once += d == 1;
        CHECK_CASE("pb_take2: every item once", once == n);
        CHECK(threads.size() <= 2);
        std::vector<std::atomic<int>> halves(n);
        pb_split2(n, [&](size_t a, size_t b) { for (size_t i = a; i < b; i++) halves[i]++; }, 2);
        once = 0;
        for (auto &d : halves) once += d == 1;
        CHECK_CASE("pb_split2: every item once", once == n);
    }
    return pb_check_report("test_split");
}
