// pointviz — reading a block of numeric rows from a file at disk speed: the data part of a PLY
// element, of a PCD file or of an XYZ-style text file. The formats' headers are parsed (and
// checked against the file) by the Python readers; this reads the rows they describe, in
// parallel, with progress and cancellation, and never trusts a count it has not checked.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <memory>
#include <new>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <sys/mman.h>

#include "pointviz/default_init.h"
#include "pointviz/progress.h"
#include "pointviz/readers/data_errors.h"
#include "pointviz/readers/numbers.h"

namespace pointviz {

/// How the rows are stored.
enum class Encoding : uint8_t { Ascii, BinaryLittle, BinaryBig };

/// One block of rows of one file.
struct TableSpec {
    std::string path;              ///< the file
    uint64_t offset = 0;           ///< first byte of the rows (after the header)
    Encoding encoding = Encoding::Ascii;
    /// Every column of a row in file order. Binary: their types give the row layout. ASCII: only
    /// the count matters (every token is parsed as a double).
    std::vector<Scalar> columns;
    /// Rows to read; -1 (ASCII only): every line to the end of the file, skipping blank lines
    /// and comment lines (first non-blank character '#' or "//").
    int64_t rows = -1;
    std::vector<uint32_t> wanted;  ///< columns returned, in this order (indices into `columns`)
    /// ASCII: a row must hold exactly `columns.size()` values; else at least that many (the
    /// extra values are ignored, as XYZ readers do).
    bool exact_columns = true;
    bool commas = false;           ///< ASCII: ',' and ';' separate values too
    /// When set, the first three wanted columns (a position p, as a row) are returned as
    /// p M + t, with M the first nine values (row-major 3x3) and t the last three: a scan placed
    /// in the common frame of a registration as it is read.
    bool transform = false;
    std::array<double, 12> affine{1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};
    /// With a row count: the first `grid_cells` lines (binary: records) after the rows are a
    /// range scan's grid (a PLY `range_grid` element: per cell, row-major with `grid_cols`
    /// cells per row, a count and that many row indices), read into Table::grid. 0: none.
    uint64_t grid_cells = 0;
    uint32_t grid_cols = 0;
    /// Binary: the scalar types of a grid record's count and of its row indices.
    Scalar grid_count = Scalar::U8;
    Scalar grid_index = Scalar::I32;
};

/// Buffers of at least this many bytes are placed on 2 MiB boundaries and offered huge pages
/// (Linux's transparent huge pages, where enabled "madvise" as numpy does for its arrays): the
/// reader's first write to a 24 MB table then faults ~12 pages in, not ~6,000.
constexpr size_t kHugePageBytes = size_t(2) << 20;
constexpr size_t kHugeBufferBytes = size_t(4) << 20;

/// DefaultInitAllocator (new elements left unwritten: the reader writes every value of a
/// table, so zero-filling it first would be one more pass over memory), with large buffers
/// offered huge pages (kHugeBufferBytes).
template <class T>
struct UninitAllocator : DefaultInitAllocator<T> {
    template <class U>
    struct rebind {
        using other = UninitAllocator<U>;
    };
    UninitAllocator() = default;
    template <class U>
    UninitAllocator(const UninitAllocator<U> &) noexcept {}
    T *allocate(size_t n) {
        if (n < kHugeBufferBytes / sizeof(T)) return std::allocator<T>::allocate(n);
        if (n > std::numeric_limits<size_t>::max() / sizeof(T)) throw std::bad_alloc();
        const size_t bytes = n * sizeof(T);
        void *p = nullptr;
        if (::posix_memalign(&p, kHugePageBytes, bytes) != 0) throw std::bad_alloc();
#ifdef MADV_HUGEPAGE
        ::madvise(p, bytes / kHugePageBytes * kHugePageBytes, MADV_HUGEPAGE);  // a hint only
#endif
        return static_cast<T *>(p);
    }
    void deallocate(T *p, size_t n) noexcept {
        if (n < kHugeBufferBytes / sizeof(T))
            std::allocator<T>::deallocate(p, n);
        else
            ::free(p);
    }
};

/// The values of a table, rows x columns, row-major.
using TableValues = std::vector<double, UninitAllocator<double>>;

/// Bounds and sum of positions: the first three wanted columns as read (before the affine
/// map), over the rows where all three are finite.
struct PositionStats {
    std::array<double, 3> lo{kInf, kInf, kInf}, hi{-kInf, -kInf, -kInf}, sum{0, 0, 0};
    uint64_t finite = 0;  ///< rows counted
    static constexpr double kInf = std::numeric_limits<double>::infinity();

    void add(const double *p) {
        if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) return;
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], p[k]);
            hi[k] = std::max(hi[k], p[k]);
            sum[k] += p[k];
        }
        ++finite;
    }
    void merge(const PositionStats &o) {
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], o.lo[k]);
            hi[k] = std::max(hi[k], o.hi[k]);
            sum[k] += o.sum[k];
        }
        finite += o.finite;
    }
};

/// The rows read from one TableSpec.
struct Table {
    TableValues values;            ///< rows x wanted.size(), row-major (unless `block` is set)
    /// When set (read_tables_joined): the rows go here instead of `values`, a block of exactly
    /// rows x wanted.size() values of a buffer that the call's tables share.
    double *block = nullptr;
    uint64_t rows = 0;
    /// ASCII with a row count: lines after the rows (a last line without '\n' counts), which
    /// belong to the file's other elements.
    uint64_t lines_after = 0;
    /// With TableSpec::grid_cells: (rows, 2) grid row and column of each row's cell, -1 for
    /// rows in no cell; a row listed by several cells keeps the last.
    std::vector<int32_t> grid;
    /// Of the positions (when at least three columns are wanted); sums are merged in row order,
    /// so they do not depend on the thread count.
    PositionStats positions;
};


/// Reads every spec into `out` (resized to match). Several specs are read in parallel, one per
/// worker; a single spec is split across workers by rows. Results never depend on `threads`.
/// Throws TruncatedData, MalformedData, std::runtime_error (I/O, bad spec) or Cancelled; with
/// several specs the error of the lowest-numbered failing spec is thrown.
void read_tables(const std::vector<TableSpec> &specs, std::vector<Table> &out, int threads,
                 Progress &progress);

/// As read_tables, with every spec's rows in one buffer, `joined`, one spec's block after the
/// other's (the scans of a registration as one cloud, without a copy to join them); each
/// table's `values` stays empty and its `block` points into `joined`. Every spec needs a row
/// count (`rows` >= 0) and they all the same number of wanted columns (else
/// std::invalid_argument, before anything is read).
void read_tables_joined(const std::vector<TableSpec> &specs, TableValues &joined,
                        std::vector<Table> &out, int threads, Progress &progress);

}  // namespace pointviz
