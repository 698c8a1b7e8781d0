// pointviz._core — runs one long core call (tree build, preprocessing, loading, rendering) on a
// worker thread while the calling thread keeps Python alive: it waits without the GIL, and every
// kPollInterval takes the GIL briefly to run pending signal handlers and report progress.
//
// Cancellation is one flag, Progress::cancel. It is set when
//   * `poll(done, total)` returns False (a progress bar, a GUI's Cancel button, the CLI's cancel
//     token set by its SIGINT handler), or
//   * `poll` or a signal handler raises (e.g. KeyboardInterrupt under Python's default SIGINT
//     handler): that exception is kept and re-raised unchanged once the worker has ended.
// The work sees the flag through Progress::check() and throws pointviz::Cancelled, which the
// module's exception translator turns into pointviz.CancelledError. No Python code ever runs on
// the worker thread, and the call returns only after the worker has ended: nothing keeps
// running (and using the caller's buffers) after an interrupt.
#pragma once

#include <nanobind/nanobind.h>

#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <mutex>
#include <optional>
#include <thread>
#include <type_traits>
#include <utility>

#ifdef __linux__
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

#include "pointviz/progress.h"

namespace pointviz {

/// How often the waiting thread wakes to run signal handlers and report progress: short enough
/// that Ctrl-C and Cancel act within a frame of a GUI (and a progress bar moves smoothly), long
/// enough that its GIL round trips (a few microseconds each) cost nothing next to the work.
constexpr std::chrono::milliseconds kPollInterval{10};

/// Options of one run.
struct RunOptions {
    /// Added to the worker's nice value (Linux; threads it starts inherit it). An interactive
    /// caller passes a positive value so that its GUI thread wins the CPU over the work; the
    /// calling thread, which briefly holds the GIL, keeps its own priority.
    int nice = 0;
};

namespace detail {

/// A Python exception taken out of the interpreter (needs the GIL to create and to restore).
class HeldPyError {
public:
    void take() {
        PyErr_Fetch(&type_, &value_, &trace_);
        PyErr_NormalizeException(&type_, &value_, &trace_);
    }
    bool held() const { return type_ != nullptr; }
    /// Puts the exception back and throws it (the GIL must be held).
    [[noreturn]] void raise() {
        PyErr_Restore(type_, value_, trace_);
        type_ = value_ = trace_ = nullptr;
        throw nanobind::python_error();
    }

private:
    PyObject *type_ = nullptr, *value_ = nullptr, *trace_ = nullptr;
};

inline void lower_priority(int nice) {
#ifdef __linux__
    if (nice <= 0) return;
    const id_t tid = id_t(syscall(SYS_gettid));
    errno = 0;
    int now = getpriority(PRIO_PROCESS, tid);
    if (errno == 0) setpriority(PRIO_PROCESS, tid, now + nice);  // best effort
#else
    (void)nice;
#endif
}

/// One wake-up of the waiting thread (GIL held): signal handlers first, then `poll`.
inline void poll_python(nanobind::handle poll, Progress &progress, HeldPyError &error) {
    if (error.held()) return;
    if (PyErr_CheckSignals() != 0) {
        error.take();
        progress.cancel = true;
        return;
    }
    if (!poll.is_valid() || poll.is_none() || progress.cancelled()) return;
    PyObject *r = PyObject_CallFunction(poll.ptr(), "KK",
                                        (unsigned long long)progress.done.load(),
                                        (unsigned long long)progress.total.load());
    if (r == nullptr) {
        error.take();
        progress.cancel = true;
        return;
    }
    if (r == Py_False) progress.cancel = true;
    Py_DECREF(r);
}

}  // namespace detail

/// Runs `work(progress)` on a worker thread; the caller (holding the GIL) waits as described at
/// the top of this file and gets work's result, or its exception, or the Python exception raised
/// by `poll` or a signal handler. `poll` may be None (signals are still handled).
template <class Work>
auto run_with_progress(Progress &progress, nanobind::handle poll, Work &&work,
                       RunOptions options = {}) -> std::invoke_result_t<Work &, Progress &> {
    using Result = std::invoke_result_t<Work &, Progress &>;
    constexpr bool is_void = std::is_void_v<Result>;
    using Slot = std::conditional_t<is_void, bool, Result>;
    std::optional<Slot> result;
    std::exception_ptr failure;
    detail::HeldPyError py_error;
    std::mutex m;
    std::condition_variable cv;
    bool finished = false;
    detail::poll_python(poll, progress, py_error);  // already cancelled: the work stops at once
    {
        nanobind::gil_scoped_release release;
        std::thread worker([&] {
            detail::lower_priority(options.nice);
            try {
                if constexpr (is_void) {
                    work(progress);
                    result.emplace(true);
                } else {
                    result.emplace(work(progress));
                }
            } catch (...) {
                failure = std::current_exception();
            }
            std::lock_guard<std::mutex> lock(m);
            finished = true;
            cv.notify_all();
        });
        std::unique_lock<std::mutex> lock(m);
        while (!cv.wait_for(lock, kPollInterval, [&] { return finished; })) {
            lock.unlock();
            {
                nanobind::gil_scoped_acquire gil;
                detail::poll_python(poll, progress, py_error);
            }
            lock.lock();
        }
        lock.unlock();
        worker.join();
    }
    if (py_error.held()) py_error.raise();
    if (failure) std::rethrow_exception(failure);
    if constexpr (!is_void) return std::move(*result);
}

}  // namespace pointviz
