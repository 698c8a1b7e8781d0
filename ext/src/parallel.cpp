// pointviz — the worker threads of parallel_for.
#include "pointviz/parallel.h"

#include <vector>

namespace pointviz {

void run_workers(int workers, void (*fn)(void *ctx, int worker), void *ctx) {
    std::vector<std::thread> pool;
    pool.reserve(size_t(workers - 1));
    for (int w = 1; w < workers; ++w) pool.emplace_back(fn, ctx, w);
    fn(ctx, 0);
    for (auto &t : pool) t.join();
}

}  // namespace pointviz
