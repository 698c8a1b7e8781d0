// pointviz — a minimal fork-join loop over index ranges. No global pool: each call spawns its
// workers and joins them, so renders stay re-entrant and a scene can be used from many threads.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <thread>

#include "pointviz/isa.h"

namespace pointviz {

/// Runs `fn(ctx, w)` for w = 1 .. workers - 1 on new threads and `fn(ctx, 0)` on the calling
/// one, then joins them. Compiled once (parallel.cpp), outside the per-instruction-set kernels
/// (isa.h), which is why it takes a plain function pointer: no library template (std::vector,
/// std::thread) is instantiated in both.
void run_workers(int workers, void (*fn)(void *ctx, int worker), void *ctx);

POINTVIZ_ISA_BEGIN

/// Number of worker threads for a request: `requested` if positive, else all cores.
inline int resolve_threads(int requested) {
    if (requested > 0) return requested;
    unsigned hw = std::thread::hardware_concurrency();
    return hw == 0 ? 1 : int(hw);
}

/// Calls `fn(begin, end, worker)` over consecutive chunks of [0, n) of at most `grain` items,
/// on `threads` workers (the calling thread is worker 0). Chunks are claimed dynamically, so the
/// partition of work depends on timing: `fn` must make results depend only on the indices.
/// `stop` (optional) is polled between chunks; once true, no new chunk starts.
template <class Fn>
void parallel_for(size_t n, size_t grain, int threads, Fn &&fn,
                  const std::atomic<bool> *stop = nullptr) {
    if (n == 0) return;
    grain = std::max<size_t>(grain, 1);
    size_t chunks = (n + grain - 1) / grain;
    int workers = int(std::min<size_t>(size_t(resolve_threads(threads)), chunks));
    std::atomic<size_t> next{0};
    auto run = [&](int worker) {
        for (;;) {
            if (stop && stop->load(std::memory_order_relaxed)) return;
            size_t c = next.fetch_add(1, std::memory_order_relaxed);
            if (c >= chunks) return;
            size_t b = c * grain;
            fn(b, std::min(n, b + grain), worker);
        }
    };
    if (workers <= 1) {
        run(0);
        return;
    }
    run_workers(workers, [](void *ctx, int w) { (*static_cast<decltype(run) *>(ctx))(w); }, &run);
}

POINTVIZ_ISA_END

}  // namespace pointviz
