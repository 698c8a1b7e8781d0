// pointviz — reading numeric rows from PLY, PCD and XYZ data blocks.
#include "pointviz/readers/table.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <exception>
#include <memory>
#include <mutex>

#include <sys/stat.h>

#include "pointviz/parallel.h"
#include "pointviz/readers/mapped_file.h"

namespace pointviz {
namespace {

/// Rows parsed between cancellation checks and progress updates (a few ms of ASCII parsing).
constexpr size_t kRowGrain = 16384;

std::string row_name(uint64_t row) { return "row " + std::to_string(row); }

/// A token for an error message: printable ASCII as is, other bytes as \xNN (messages must be
/// valid text whatever the file holds), at most kMaxQuoted bytes of it.
std::string quoted_token(const char *b, const char *e) {
    constexpr ptrdiff_t kMaxQuoted = 40;
    static const char hex[] = "0123456789abcdef";
    std::string out;
    for (const char *p = b; p != e && p - b < kMaxQuoted; ++p) {
        unsigned char c = static_cast<unsigned char>(*p);
        if (c >= 0x20 && c < 0x7f && c != '\\') {
            out += char(c);
        } else {
            out += "\\x";
            out += hex[c >> 4];
            out += hex[c & 15];
        }
    }
    return out;
}

/// First error of a parallel loop, by the lowest item that failed. Errors do not stop the loop
/// (only cancellation does), so the error reported never depends on timing or thread count.
struct FirstError {
    std::mutex mu;
    std::exception_ptr err;
    uint64_t item = ~uint64_t(0);

    void record(uint64_t at) {
        std::lock_guard<std::mutex> lock(mu);
        if (at < item) {
            item = at;
            err = std::current_exception();
        }
    }
    /// Throws the first error, or Cancelled if the loop was stopped before finishing.
    void rethrow(const Progress &progress) {
        if (err) std::rethrow_exception(err);
        progress.check();
    }
};

/// Parses one ASCII row [b, e) into `dst` (the wanted columns); `slot[c]` is the output index of
/// column c or -1.
void parse_row(const char *b, const char *e, const TableSpec &spec, const std::vector<int> &slot,
               double *dst, uint64_t row) {
    const size_t ncols = spec.columns.size();
    size_t c = 0;
    const char *p = b;
    for (;;) {
        while (p != e && is_separator(*p, spec.commas)) ++p;
        if (p == e) break;
        const char *t = p;
        while (p != e && !is_separator(*p, spec.commas)) ++p;
        if (c < ncols) {
            double v;
            if (!parse_number(t, p, v)) {
                throw MalformedData(row_name(row) + " holds a non-number '" +
                                    quoted_token(t, p) + "'");
            }
            if (slot[c] >= 0) dst[slot[c]] = v;
        }
        ++c;
        if (c > ncols && !spec.exact_columns) break;  // extra values are ignored
    }
    if (c < ncols || (spec.exact_columns && c != ncols))
        throw MalformedData(row_name(row) + " has " + std::to_string(c) + " values, expected " +
                            std::to_string(ncols));
}

/// Whether the line [b, e) holds nothing to read: blank, or a comment (text tables only).
bool skip_line(const char *b, const char *e) {
    while (b != e && is_separator(*b, false)) ++b;
    return b == e || *b == '#' || (e - b >= 2 && b[0] == '/' && b[1] == '/');
}

/// Positions (first three values) of rows [b, e): adds them to `stats` as read, then applies
/// the spec's affine map.
void place_rows(const TableSpec &spec, double *values, size_t nw, size_t b, size_t e,
                PositionStats &stats) {
    if (nw < 3) return;
    const std::array<double, 12> &m = spec.affine;
    for (size_t r = b; r < e; ++r) {
        double *v = values + r * nw;
        stats.add(v);
        if (!spec.transform) continue;
        const double x = v[0], y = v[1], z = v[2];
        for (int j = 0; j < 3; ++j) v[j] = x * m[j] + y * m[3 + j] + z * m[6 + j] + m[9 + j];
    }
}

/// Per-chunk statistics merged in chunk order (deterministic sums).
void merge_stats(const std::vector<PositionStats> &parts, PositionStats &out) {
    out = PositionStats{};
    for (const PositionStats &p : parts) out.merge(p);
}

/// Parses a non-negative decimal integer at p (after separators); false if there is none.
bool parse_index(const char *&p, const char *e, uint64_t &v) {
    while (p != e && is_separator(*p, false)) ++p;
    if (p == e || *p < '0' || *p > '9') return false;
    v = 0;
    while (p != e && *p >= '0' && *p <= '9') {
        v = v * 10 + uint64_t(*p - '0');
        if (v > (uint64_t(1) << 40)) return false;
        ++p;
    }
    return p == e || is_separator(*p, false);
}

/// Whether the spec asks for a range grid that Table::grid can hold.
bool has_grid(const TableSpec &spec) {
    return spec.grid_cells > 0 && spec.grid_cols > 0 &&
           spec.grid_cells / spec.grid_cols < uint64_t(INT32_MAX);
}

/// The errors of a range grid's cell `c` (ASCII line or binary record alike).
MalformedData grid_without_count(uint64_t c) {
    return MalformedData("range_grid row " + std::to_string(c) + " has no count");
}
MalformedData grid_bad_index(uint64_t c) {
    return MalformedData("range_grid row " + std::to_string(c) +
                         " lists a vertex index that is missing or out of range");
}

/// Records that row `v` lies in the range grid's cell `c` (row-major, spec.grid_cols a row).
void place_in_grid(std::vector<int32_t> &grid, uint64_t v, uint64_t c, const TableSpec &spec) {
    grid[2 * v] = int32_t(c / spec.grid_cols);
    grid[2 * v + 1] = int32_t(c % spec.grid_cols);
}

/// One line [b, e) of a range grid: cell `c`'s count and row indices into `grid`.
void parse_grid_line(const char *b, const char *e, uint64_t c, const TableSpec &spec,
                     uint64_t nrows, std::vector<int32_t> &grid) {
    uint64_t count = 0, v = 0;
    const char *p = b;
    if (!parse_index(p, e, count)) throw grid_without_count(c);
    for (uint64_t m = 0; m < count; ++m) {
        if (!parse_index(p, e, v) || v >= nrows) throw grid_bad_index(c);
        place_in_grid(grid, v, c, spec);
    }
}

/// Where `count` values of a table's rows go: its `block` of a joined buffer (sized for the
/// spec's row count, which the caller has checked the rows are), else its own `values`.
double *row_storage(Table &out, size_t count) {
    if (out.block != nullptr) return out.block;
    out.values.resize(count);
    return out.values.data();
}

void read_ascii(const TableSpec &spec, const MappedBytes &buf, Table &out, int threads,
                Progress &progress, const std::vector<int> &slot) {
    const char *data = buf.data();
    const char *end = data + buf.size();
    // Begin/end byte offsets of each row's line.
    std::vector<uint64_t> bounds;
    if (spec.rows >= 0)  // every row takes at least two bytes: a lying count cannot reserve more
        bounds.reserve(2 * std::min<size_t>(size_t(spec.rows), buf.size() / 2 + 1));
    const char *p = data;
    size_t since_check = 0;
    while (p < end && (spec.rows < 0 || int64_t(bounds.size() / 2) < spec.rows)) {
        const char *nl = static_cast<const char *>(std::memchr(p, '\n', size_t(end - p)));
        const char *le = nl ? nl : end;
        if (spec.rows >= 0 || !skip_line(p, le)) {
            bounds.push_back(uint64_t(p - data));
            bounds.push_back(uint64_t(le - data));
        }
        p = nl ? nl + 1 : end;
        if (++since_check == kRowGrain) {
            since_check = 0;
            progress.check();
        }
    }
    const uint64_t nrows = bounds.size() / 2;
    if (spec.rows >= 0 && nrows < uint64_t(spec.rows))
        throw TruncatedData("the data ends after " + std::to_string(nrows) + " of the " +
                            std::to_string(spec.rows) + " rows");
    if (spec.rows >= 0) {  // lines after the rows, for the file's other elements
        const bool grid = has_grid(spec);
        if (grid) out.grid.assign(2 * size_t(nrows), -1);
        uint64_t after = 0;
        const char *q = p;
        while (q < end) {
            const char *nl = static_cast<const char *>(std::memchr(q, '\n', size_t(end - q)));
            if (grid && after < spec.grid_cells)
                parse_grid_line(q, nl ? nl : end, after, spec, nrows, out.grid);
            ++after;
            q = nl ? nl + 1 : end;
            if ((after & (kRowGrain - 1)) == 0) progress.check();
        }
        out.lines_after = after;
    }
    const size_t nw = spec.wanted.size();
    out.rows = nrows;
    double *values = row_storage(out, size_t(nrows) * nw);
    FirstError first;
    std::atomic<uint64_t> advanced{0};
    std::vector<PositionStats> parts((size_t(nrows) + kRowGrain - 1) / kRowGrain);
    parallel_for(size_t(nrows), kRowGrain, threads, [&](size_t b, size_t e, int) {
        try {
            progress.check();
            for (size_t r = b; r < e; ++r)
                parse_row(data + bounds[2 * r], data + bounds[2 * r + 1], spec, slot,
                          values + r * nw, r);
            place_rows(spec, values, nw, b, e, parts[b / kRowGrain]);
            const uint64_t bytes = bounds[2 * (e - 1) + 1] - bounds[2 * b];
            advanced.fetch_add(bytes, std::memory_order_relaxed);
            progress.advance(bytes);
        } catch (...) {
            first.record(b);
        }
    }, &progress.cancel);
    first.rethrow(progress);
    merge_stats(parts, out.positions);
    progress.advance(buf.size() - advanced.load());  // newlines, skipped and trailing lines
}

/// A binary range grid: spec.grid_cells records from byte `at` of `buf` (each a count, then
/// that many row indices), into out.grid.
void read_binary_grid(const TableSpec &spec, const MappedBytes &buf, uint64_t at, uint64_t nrows,
                      bool swap, Table &out) {
    const size_t count_bytes = scalar_size(spec.grid_count);
    const size_t index_bytes = scalar_size(spec.grid_index);
    out.grid.assign(2 * size_t(nrows), -1);
    const uint64_t size = buf.size();
    for (uint64_t c = 0; c < spec.grid_cells; ++c) {
        if (size - at < count_bytes)
            throw TruncatedData("the range_grid ends after " + std::to_string(c) + " of its " +
                                std::to_string(spec.grid_cells) + " cells");
        double count = decode_scalar(buf.data() + at, spec.grid_count, swap);
        at += count_bytes;
        if (!(count >= 0) || count != std::floor(count)) throw grid_without_count(c);
        if (uint64_t(count) > (size - at) / index_bytes)
            throw TruncatedData("the range_grid ends in its cell " + std::to_string(c) +
                                " of " + std::to_string(spec.grid_cells));
        for (uint64_t m = 0; m < uint64_t(count); ++m, at += index_bytes) {
            double v = decode_scalar(buf.data() + at, spec.grid_index, swap);
            if (!(v >= 0 && v < double(nrows)) || v != std::floor(v)) throw grid_bad_index(c);
            place_in_grid(out.grid, uint64_t(v), c, spec);
        }
    }
}

void read_binary(const TableSpec &spec, const MappedBytes &buf, Table &out, int threads,
                 Progress &progress) {
    std::vector<size_t> col_offset(spec.columns.size());
    size_t row_bytes = 0;
    for (size_t c = 0; c < spec.columns.size(); ++c) {
        col_offset[c] = row_bytes;
        row_bytes += scalar_size(spec.columns[c]);
    }
    if (spec.rows < 0) throw std::runtime_error("binary tables need a row count");
    const uint64_t nrows = uint64_t(spec.rows);
    if (row_bytes == 0) throw std::runtime_error("binary rows of zero bytes");
    if (nrows > buf.size() / row_bytes)
        throw TruncatedData("the rows need " + std::to_string(nrows) + " x " +
                            std::to_string(row_bytes) + " bytes, the data has " +
                            std::to_string(buf.size()));
    const bool swap = spec.encoding == Encoding::BinaryBig;
    const size_t nw = spec.wanted.size();
    out.rows = nrows;
    double *values = row_storage(out, size_t(nrows) * nw);
    FirstError first;
    const size_t grain = kRowGrain * 8;
    std::vector<PositionStats> parts((size_t(nrows) + grain - 1) / grain);
    parallel_for(size_t(nrows), grain, threads, [&](size_t b, size_t e, int) {
        try {
            progress.check();
            for (size_t r = b; r < e; ++r) {
                const char *row = buf.data() + r * row_bytes;
                double *dst = values + r * nw;
                for (size_t k = 0; k < nw; ++k) {
                    uint32_t c = spec.wanted[k];
                    dst[k] = decode_scalar(row + col_offset[c], spec.columns[c], swap);
                }
            }
            place_rows(spec, values, nw, b, e, parts[b / grain]);
            progress.advance((e - b) * row_bytes);
        } catch (...) {
            first.record(b);
        }
    }, &progress.cancel);
    first.rethrow(progress);
    merge_stats(parts, out.positions);
    if (has_grid(spec)) read_binary_grid(spec, buf, nrows * row_bytes, nrows, swap, out);
    progress.advance(buf.size() - nrows * row_bytes);
}

void read_one(const TableSpec &spec, Table &out, int threads, Progress &progress) {
    if (spec.columns.empty()) throw std::runtime_error("a table needs at least one column");
    std::vector<int> slot(spec.columns.size(), -1);
    for (size_t k = 0; k < spec.wanted.size(); ++k) {
        if (spec.wanted[k] >= spec.columns.size())
            throw std::runtime_error("wanted column " + std::to_string(spec.wanted[k]) +
                                     " of a " + std::to_string(spec.columns.size()) +
                                     "-column table");
        slot[spec.wanted[k]] = int(k);
    }
    uint64_t limit = ~uint64_t(0);
    // binary: the rows, not what follows (unless a range grid does)
    if (spec.encoding != Encoding::Ascii && spec.rows >= 0 && !has_grid(spec)) {
        uint64_t row_bytes = 0;
        for (Scalar c : spec.columns) row_bytes += scalar_size(c);
        if (uint64_t(spec.rows) <= ~uint64_t(0) / row_bytes) limit = uint64_t(spec.rows) * row_bytes;
    }
    MappedBytes buf(spec.path, spec.offset, limit);
    progress.total.fetch_add(buf.size(), std::memory_order_relaxed);  // units: bytes
    progress.check();
    if (spec.encoding == Encoding::Ascii)
        read_ascii(spec, buf, out, threads, progress, slot);
    else
        read_binary(spec, buf, out, threads, progress);
}

}  // namespace

namespace {

/// The most rows the spec's file can hold from its offset: one byte each (ASCII), or the
/// columns' bytes (binary). 0 for a file that cannot be read (its read then says why).
uint64_t max_rows(const TableSpec &spec) {
    struct stat st;
    if (::stat(spec.path.c_str(), &st) != 0 || uint64_t(st.st_size) < spec.offset) return 0;
    uint64_t row_bytes = 1;
    if (spec.encoding != Encoding::Ascii) {
        row_bytes = 0;
        for (Scalar c : spec.columns) row_bytes += scalar_size(c);
    }
    return (uint64_t(st.st_size) - spec.offset) / std::max<uint64_t>(row_bytes, 1);
}

/// Reads every spec into its table of `out` (already sized, blocks set where joined).
void read_each(const std::vector<TableSpec> &specs, std::vector<Table> &out, int threads,
               Progress &progress) {
    if (specs.size() == 1) {
        read_one(specs[0], out[0], threads, progress);
        return;
    }
    // Several files (the scans of a .conf): one file per worker, each read serially.
    FirstError first;
    parallel_for(specs.size(), 1, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            try {
                read_one(specs[i], out[i], 1, progress);
            } catch (...) {
                first.record(i);
            }
        }
    }, &progress.cancel);
    first.rethrow(progress);
}

}  // namespace

void read_tables(const std::vector<TableSpec> &specs, std::vector<Table> &out, int threads,
                 Progress &progress) {
    out.assign(specs.size(), Table{});
    read_each(specs, out, threads, progress);
}

void read_tables_joined(const std::vector<TableSpec> &specs, TableValues &joined,
                        std::vector<Table> &out, int threads, Progress &progress) {
    const size_t nw = specs.empty() ? 0 : specs[0].wanted.size();
    uint64_t total = 0;
    for (const TableSpec &spec : specs) {
        if (spec.rows < 0)
            throw std::invalid_argument("joined tables need a row count for every spec");
        if (spec.wanted.size() != nw)
            throw std::invalid_argument("joined tables need the same number of wanted columns");
        // the buffer is sized from the counts before any row is read: a count is trusted only
        // as far as its file could hold it (a row takes at least one byte; binary: its size)
        if (uint64_t(spec.rows) > max_rows(spec))
            throw TruncatedData("the data ends before the " + std::to_string(spec.rows) +
                                " rows of " + spec.path);
        total += uint64_t(spec.rows);  // (each count is at most its file's size: no overflow)
    }
    joined.resize(size_t(total) * nw);
    out.assign(specs.size(), Table{});
    size_t at = 0;
    for (size_t i = 0; i < specs.size(); ++i) {
        out[i].block = joined.data() + at;
        at += size_t(specs[i].rows) * nw;
    }
    read_each(specs, out, threads, progress);
}

}  // namespace pointviz
