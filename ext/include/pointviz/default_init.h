// pointviz — vectors whose new elements are left default-initialised (no zero fill).
#pragma once

#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

namespace pointviz {

/// std::allocator, except that the elements a vector adds without a value (`resize(n)`,
/// `vector(n)`) are default-initialised: for integers and doubles, not written at all. For
/// tables that workers fill, every element: zero-filling one first was one thread faulting all
/// its pages in while the other cores waited (a 124 MB neighbour table of 1M points, ~70 ms);
/// left unfilled, the workers fault in the pages they write.
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
    template <class U>
    struct rebind {
        using other = DefaultInitAllocator<U>;
    };
    DefaultInitAllocator() = default;
    template <class U>
    DefaultInitAllocator(const DefaultInitAllocator<U> &) noexcept {}
    template <class U>
    void construct(U *p) noexcept(std::is_nothrow_default_constructible_v<U>) {
        ::new (static_cast<void *>(p)) U;
    }
    template <class U, class... Args>
    void construct(U *p, Args &&...args) {
        ::new (static_cast<void *>(p)) U(std::forward<Args>(args)...);
    }
};

/// A vector whose `resize(n)` / `vector(n)` leaves the new elements unwritten (see above).
template <class T>
using UnfilledVector = std::vector<T, DefaultInitAllocator<T>>;

}  // namespace pointviz
