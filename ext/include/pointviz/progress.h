// pointviz — progress and cooperative cancellation of one long-running core call (tree build,
// preprocessing, loading, rendering). No globals: each call gets its own Progress, shared by the
// worker threads doing the work and the thread that watches it (and reports to Python).
#pragma once

#include <atomic>
#include <cstdint>
#include <stdexcept>

namespace pointviz {

/// Thrown out of long-running work once its Progress has been cancelled; the binding layer turns
/// it into the Python package's CancelledError.
struct Cancelled : std::runtime_error {
    Cancelled() : std::runtime_error("cancelled") {}
};

/// Shared state of one long-running call. Workers add to `done` and poll `cancelled()` at least
/// every few milliseconds of work; the watcher reads `done` / `total` and sets `cancel`.
struct Progress {
    std::atomic<bool> cancel{false};     ///< set by the watcher: stop as soon as possible
    std::atomic<uint64_t> done{0};       ///< units of work finished so far
    std::atomic<uint64_t> total{0};      ///< units expected (0 while unknown)

    bool cancelled() const { return cancel.load(std::memory_order_relaxed); }
    /// Throws Cancelled once the call has been cancelled.
    void check() const {
        if (cancelled()) throw Cancelled();
    }
    void advance(uint64_t n = 1) { done.fetch_add(n, std::memory_order_relaxed); }
};

/// `p->check()` for an optional Progress.
inline void check_cancel(const Progress *p) {
    if (p) p->check();
}

}  // namespace pointviz
