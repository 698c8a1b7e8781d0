// pointviz — tests of the core's table and face readers (readers/table.h, readers/faces.h,
// readers/numbers.h) on their own,
// run under ASan + UBSan by `make sanitize`. Values are checked against what wrote them (exact
// round trips of %.17g text and of binary rows); damaged files (random bytes, truncation, random
// specs) must end in the reader's own errors, never in a crash, a hang or a read out of bounds.
//
// Random cases are seeded by their index; a failure prints the case to replay it.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "pointviz/readers/faces.h"
#include "pointviz/readers/lzf.h"
#include "pointviz/readers/obj.h"
#include "pointviz/readers/numbers.h"
#include "pointviz/readers/table.h"
#include "check.h"

using namespace pointviz;

namespace {


std::string temp_path(const std::string &name) {
    const char *dir = std::getenv("TMPDIR");
    return std::string(dir ? dir : "/tmp") + "/pointviz_reader_tests_" + name;
}

void write_file(const std::string &path, const std::string &bytes) {
    std::FILE *f = std::fopen(path.c_str(), "wb");
    if (!f) throw std::runtime_error("cannot write " + path);
    std::fwrite(bytes.data(), 1, bytes.size(), f);
    std::fclose(f);
}

/// What reading one spec gave: the table, or the kind of error.
enum class Outcome { Ok, Truncated, Malformed, Other, Cancelled };

/// What calling `read` gave: Ok, or the kind of error it threw.
template <class Fn>
Outcome outcome_of(Fn &&read) {
    try {
        read();
    } catch (const TruncatedData &) {
        return Outcome::Truncated;
    } catch (const MalformedData &) {
        return Outcome::Malformed;
    } catch (const Cancelled &) {
        return Outcome::Cancelled;
    } catch (const std::runtime_error &) {
        return Outcome::Other;
    }
    return Outcome::Ok;
}

Outcome read_one(const TableSpec &spec, Table &out, int threads = 0) {
    std::vector<Table> tables;
    Progress progress;
    Outcome o = outcome_of([&] { read_tables({spec}, tables, threads, progress); });
    if (o == Outcome::Ok) out = std::move(tables[0]);
    return o;
}

/// Whether a table holds exactly these values.
bool same(const TableValues &got, const std::vector<double> &want) {
    return std::equal(got.begin(), got.end(), want.begin(), want.end());
}

TableSpec ascii_spec(const std::string &path, size_t ncols, int64_t rows) {
    TableSpec s;
    s.path = path;
    s.encoding = Encoding::Ascii;
    s.columns.assign(ncols, Scalar::F64);
    s.rows = rows;
    for (size_t c = 0; c < ncols; ++c) s.wanted.push_back(uint32_t(c));
    return s;
}

void test_parse_number() {
    struct Case { const char *text; bool ok; double value; };
    const double inf = std::numeric_limits<double>::infinity();
    const Case cases[] = {
        {"0", true, 0.0}, {"-0.5", true, -0.5}, {"+2.5", true, 2.5}, {"1e3", true, 1000.0},
        {"-1.25E-2", true, -0.0125}, {".5", true, 0.5}, {"5.", true, 5.0},
        {"inf", true, inf}, {"-Infinity", true, -inf}, {"1e999", true, inf},
        {"-1e999", true, -inf}, {"1e-999", true, 0.0},
        {"", false, 0}, {"+", false, 0}, {"-", false, 0}, {"--1", false, 0}, {"+-1", false, 0},
        {"1.0x", false, 0}, {"x", false, 0}, {"1e", false, 0}, {"e5", false, 0},
        {"1,5", false, 0}, {"0x10", false, 0}, {"1 2", false, 0},
    };
    for (const Case &c : cases) {
        double v = -12345.0;
        bool ok = parse_number(c.text, c.text + std::strlen(c.text), v);
        CHECK(ok == c.ok, "parse_number(\"%s\") returned %d", c.text, int(ok));
        if (ok && c.ok) CHECK(v == c.value, "parse_number(\"%s\") = %g, want %g", c.text, v, c.value);
    }
    double v = 0;
    CHECK(parse_number("nan", "nan" + 3, v) && std::isnan(v), "nan");
    CHECK(parse_number("-NaN", "-NaN" + 4, v) && std::isnan(v), "-NaN");
    // the fast path gives from_chars' double on the short decimals scans are written with
    std::mt19937_64 g(7);
    const char *formats[] = {"%.6g", "%.7g", "%.9g", "%.15g", "%.3e", "%.8f", "%.0f"};
    for (int i = 0; i < 20000; ++i) {
        double x = std::ldexp(double(int64_t(g() >> 11)) / double(1ull << 53), int(g() % 120) - 60);
        char buf[64];
        int n = std::snprintf(buf, sizeof buf, formats[i % 7], i % 2 ? x : -x);
        double fast = 0, oracle = 0;
        const char *digits = buf[0] == '-' ? buf + 1 : buf;
        bool took = parse_simple_decimal(digits, buf + n, fast);
        std::from_chars(digits, buf + n, oracle);
        CHECK(!took || fast == oracle, "fast path on '%s': %.17g vs %.17g", buf, fast, oracle);
        double v = 0;
        CHECK(parse_number(buf, buf + n, v) && v == (buf[0] == '-' ? -oracle : oracle),
              "parse_number('%s')", buf);
    }
    // %.17g round trips exactly
    std::mt19937_64 gen(1);
    std::uniform_real_distribution<double> u(-1e6, 1e6);
    for (int i = 0; i < 2000; ++i) {
        double x = i % 3 == 0 ? u(gen) : u(gen) * std::pow(10.0, double(int(gen() % 80) - 40));
        char buf[64];
        int n = std::snprintf(buf, sizeof buf, "%.17g", x);
        double y = 0;
        CHECK(parse_number(buf, buf + n, y) && y == x, "round trip %d: %s -> %.17g", i, buf, y);
    }
}

void test_decode_scalar() {
    unsigned char le[8] = {0x01, 0x02, 0x03, 0x04, 0, 0, 0, 0};
    const char *p = reinterpret_cast<const char *>(le);
    CHECK(decode_scalar(p, Scalar::U16, false) == 0x0201, "u16 le");
    CHECK(decode_scalar(p, Scalar::U16, true) == 0x0102, "u16 be");
    CHECK(decode_scalar(p, Scalar::U32, true) == double(0x01020304u), "u32 be");
    unsigned char neg[2] = {0xff, 0xff};
    CHECK(decode_scalar(reinterpret_cast<const char *>(neg), Scalar::I16, false) == -1.0, "i16");
    CHECK(decode_scalar(reinterpret_cast<const char *>(neg), Scalar::I8, false) == -1.0, "i8");
    float f = -3.5f;
    unsigned char fb[4];
    std::memcpy(fb, &f, 4);
    unsigned char fr[4] = {fb[3], fb[2], fb[1], fb[0]};
    CHECK(decode_scalar(reinterpret_cast<const char *>(fr), Scalar::F32, true) == -3.5, "f32 be");
}

/// ASCII rows written with %.17g read back exactly, for any thread count; lines after the rows
/// are counted; the header offset is honoured.
void test_ascii_round_trip() {
    std::mt19937_64 gen(2);
    std::normal_distribution<double> nd;
    const size_t rows = 40000, cols = 4;  // several chunks of rows
    std::vector<double> want(rows * cols);
    std::string text = "header line\nend_header\n";
    const size_t offset = text.size();
    for (size_t r = 0; r < rows; ++r) {
        for (size_t c = 0; c < cols; ++c) {
            want[r * cols + c] = nd(gen) * 100.0;
            char buf[64];
            std::snprintf(buf, sizeof buf, c ? " %.17g" : "%.17g", want[r * cols + c]);
            text += buf;
        }
        text += r % 7 == 0 ? " \r\n" : "\n";
    }
    text += "3 1 2\n4 1 2 3 4";  // two more lines (a list element), the last without '\n'
    std::string path = temp_path("ascii.txt");
    write_file(path, text);
    TableSpec spec = ascii_spec(path, cols, int64_t(rows));
    spec.offset = offset;
    spec.wanted = {2, 0};
    Table ref;
    for (int threads : {1, 2, 3, 8}) {
        Table t;
        CHECK(read_one(spec, t, threads) == Outcome::Ok, "threads %d", threads);
        CHECK(t.rows == rows && t.lines_after == 2, "threads %d: rows %llu after %llu", threads,
              (unsigned long long)t.rows, (unsigned long long)t.lines_after);
        bool exact = t.values.size() == rows * 2;
        for (size_t r = 0; exact && r < rows; ++r)
            exact = t.values[2 * r] == want[r * cols + 2] && t.values[2 * r + 1] == want[r * cols];
        CHECK(exact, "threads %d: values differ from those written", threads);
    }
    // one row more than the file holds (the list lines are not numbers of 4 columns)
    spec.rows = int64_t(rows) + 3;
    Table t;
    CHECK(read_one(spec, t) == Outcome::Truncated, "rows beyond the end");
    spec.rows = int64_t(rows) + 1;
    CHECK(read_one(spec, t) == Outcome::Malformed, "a 4-value list line read as a row");
    spec.offset = text.size() + 10;
    CHECK(read_one(spec, t) == Outcome::Truncated, "offset past the end");
    std::remove(path.c_str());
}

void test_ascii_errors_name_the_first_bad_row() {
    std::string path = temp_path("bad.txt");
    std::string text;
    for (int r = 0; r < 50000; ++r) text += r == 30001 || r == 45000 ? "1 2\n" : "1 2 3\n";
    write_file(path, text);
    for (int threads : {1, 2, 4}) {
        std::vector<Table> out;
        Progress p;
        std::string msg;
        try {
            read_tables({ascii_spec(path, 3, 50000)}, out, threads, p);
        } catch (const MalformedData &e) {
            msg = e.what();
        }
        CHECK(msg == "row 30001 has 2 values, expected 3", "threads %d: '%s'", threads, msg.c_str());
    }
    write_file(path, "1 2 3\n4 \xff\x80 6\n");
    std::vector<Table> out;
    Progress p;
    std::string msg;
    try {
        read_tables({ascii_spec(path, 3, 2)}, out, 1, p);
    } catch (const MalformedData &e) {
        msg = e.what();
    }
    CHECK(msg == "row 1 holds a non-number '\\xff\\x80'", "bytes in the message: '%s'", msg.c_str());
    std::remove(path.c_str());
}

void test_text_tables_skip_blank_and_comment_lines() {
    std::string path = temp_path("points.xyz");
    write_file(path, "# x y z\n\n1,2,3\n  // note\n4;5;6;7\n\t\n-1 -2 -3 extra\n");
    TableSpec spec = ascii_spec(path, 3, -1);
    spec.exact_columns = false;
    spec.commas = true;
    Table t;
    CHECK(read_one(spec, t) == Outcome::Ok, "text table");
    const std::vector<double> want = {1, 2, 3, 4, 5, 6, -1, -2, -3};
    CHECK(t.rows == 3 && same(t.values, want), "text rows %llu", (unsigned long long)t.rows);
    std::remove(path.c_str());
}

void test_binary_round_trip_both_endians() {
    std::mt19937_64 gen(3);
    const size_t rows = 70000;
    const std::vector<Scalar> cols = {Scalar::F32, Scalar::U8, Scalar::F64, Scalar::I16};
    for (Encoding enc : {Encoding::BinaryLittle, Encoding::BinaryBig}) {
        std::string bytes = "HEAD";
        std::vector<double> want;
        for (size_t r = 0; r < rows; ++r) {
            float f = float(int64_t(gen() % 2000001) - 1000000) / 7.0f;
            uint8_t u = uint8_t(gen());
            double d = double(int64_t(gen())) * 1e-9;
            int16_t i = int16_t(gen());
            unsigned char raw[15];
            std::memcpy(raw, &f, 4);
            raw[4] = u;
            std::memcpy(raw + 5, &d, 8);
            std::memcpy(raw + 13, &i, 2);
            if (enc == Encoding::BinaryBig) {
                std::reverse(raw, raw + 4);
                std::reverse(raw + 5, raw + 13);
                std::reverse(raw + 13, raw + 15);
            }
            bytes.append(reinterpret_cast<char *>(raw), 15);
            want.insert(want.end(), {double(i), double(f), d, double(u)});
        }
        std::string path = temp_path("binary.bin");
        write_file(path, bytes + "trailing bytes of other elements");
        TableSpec spec;
        spec.path = path;
        spec.offset = 4;
        spec.encoding = enc;
        spec.columns = cols;
        spec.rows = int64_t(rows);
        spec.wanted = {3, 0, 2, 1};
        for (int threads : {1, 2, 5}) {
            Table t;
            CHECK(read_one(spec, t, threads) == Outcome::Ok && same(t.values, want),
                  "binary %d threads %d", int(enc), threads);
        }
        write_file(path, bytes.substr(0, bytes.size() - 1));
        Table t;
        CHECK(read_one(spec, t) == Outcome::Truncated, "binary truncated by one byte");
        std::remove(path.c_str());
    }
}

/// The scans of a registration: several files in one call give what each gives alone, and the
/// error of the first failing file is the one thrown.
void test_several_files() {
    std::vector<TableSpec> specs;
    std::vector<std::vector<double>> alone;
    for (int k = 0; k < 7; ++k) {
        std::string path = temp_path("scan" + std::to_string(k) + ".txt");
        std::string text;
        for (int r = 0; r < 1000 + 300 * k; ++r)
            text += std::to_string(k) + " " + std::to_string(r) + " " + std::to_string(-r) + "\n";
        write_file(path, text);
        specs.push_back(ascii_spec(path, 3, 1000 + 300 * k));
        Table t;
        read_one(specs.back(), t);
        alone.emplace_back(t.values.begin(), t.values.end());
    }
    std::vector<Table> out;
    Progress p;
    read_tables(specs, out, 3, p);
    bool equal = out.size() == specs.size();
    for (size_t k = 0; equal && k < out.size(); ++k) equal = same(out[k].values, alone[k]);
    CHECK(equal, "several files differ from each read alone");
    uint64_t bytes = 0;
    for (const TableSpec &s : specs) {
        std::FILE *f = std::fopen(s.path.c_str(), "rb");
        std::fseek(f, 0, SEEK_END);
        bytes += uint64_t(std::ftell(f));
        std::fclose(f);
    }
    CHECK(p.total.load() == bytes && p.done.load() == bytes, "progress %llu of %llu, %llu bytes",
          (unsigned long long)p.done.load(), (unsigned long long)p.total.load(),
          (unsigned long long)bytes);
    specs[2].rows += 5;  // truncated
    specs[5].rows += 5;
    std::string msg;
    try {
        read_tables(specs, out, 3, p);
    } catch (const TruncatedData &e) {
        msg = e.what();
    }
    CHECK(msg.find("of the 1605 rows") != std::string::npos, "first failing file: '%s'", msg.c_str());
    Progress cancelled;
    cancelled.cancel = true;
    bool threw = false;
    try {
        read_tables(specs, out, 2, cancelled);
    } catch (const Cancelled &) {
        threw = true;
    }
    CHECK(threw, "a cancelled read did not throw Cancelled");
    for (const TableSpec &s : specs) std::remove(s.path.c_str());
}

/// Several files read into one buffer: each file's block holds what it gives alone, in order,
/// for any thread count; a buffer large enough for huge pages (kHugeBufferBytes) too. Counts
/// are checked against the files before the buffer is sized; specs that cannot share one buffer
/// are refused before anything is read.
void test_joined_files() {
    std::vector<TableSpec> specs;
    std::vector<double> want;
    for (int k = 0; k < 5; ++k) {
        std::string path = temp_path("joined" + std::to_string(k));
        const int64_t rows = k == 3 ? 200000 : 700 + 300 * k;  // 200k x 3 doubles: 4.8 MB
        if (k % 2 == 0) {
            std::string text;
            for (int64_t r = 0; r < rows; ++r)
                text += std::to_string(k) + " " + std::to_string(r) + " " + std::to_string(-r) + "\n";
            write_file(path, text);
            specs.push_back(ascii_spec(path, 3, rows));
        } else {
            std::string bytes;
            for (int64_t r = 0; r < rows; ++r) {
                const float row[3] = {float(k), float(r), float(-r)};
                bytes.append(reinterpret_cast<const char *>(row), sizeof row);
            }
            write_file(path, bytes);
            TableSpec spec;
            spec.path = path;
            spec.encoding = Encoding::BinaryLittle;
            spec.columns = {Scalar::F32, Scalar::F32, Scalar::F32};
            spec.rows = rows;
            spec.wanted = {0, 1, 2};
            specs.push_back(spec);
        }
        Table t;
        read_one(specs.back(), t);
        want.insert(want.end(), t.values.begin(), t.values.end());
    }
    for (int threads : {1, 2, 3}) {
        TableValues joined;
        std::vector<Table> out;
        Progress p;
        read_tables_joined(specs, joined, out, threads, p);
        bool blocks = out.size() == specs.size();
        size_t at = 0;
        for (size_t k = 0; blocks && k < out.size(); ++k) {
            blocks = out[k].values.empty() && out[k].block == joined.data() + at &&
                     out[k].rows == uint64_t(specs[k].rows);
            at += size_t(specs[k].rows) * 3;
        }
        CHECK(blocks, "joined blocks misplaced (threads %d)", threads);
        CHECK(same(joined, want), "joined values differ from each file read alone (threads %d)",
              threads);
    }
    bool reserved = false;
    auto outcome = [&](std::vector<TableSpec> s) {
        TableValues joined;
        std::vector<Table> out;
        Progress p;
        Outcome o = Outcome::Ok;
        try {
            read_tables_joined(s, joined, out, 2, p);
        } catch (const TruncatedData &) {
            o = Outcome::Truncated;
        } catch (const std::invalid_argument &) {
            o = Outcome::Malformed;
        }
        reserved = !joined.empty();
        return o;
    };
    std::vector<TableSpec> lying = specs;
    lying[1].rows = int64_t(1) << 60;  // binary: far beyond the file
    CHECK(outcome(lying) == Outcome::Truncated && !reserved, "joined binary 2^60 rows");
    lying = specs;
    lying[2].rows = int64_t(1) << 50;  // ASCII: more rows than the file has bytes
    CHECK(outcome(lying) == Outcome::Truncated && !reserved, "joined ascii 2^50 rows");
    lying = specs;
    lying[4].rows += 1;  // within the file's bytes, beyond its rows: found by the read
    CHECK(outcome(lying) == Outcome::Truncated, "joined ascii one row short");
    lying = specs;
    lying[3].rows += 1;
    CHECK(outcome(lying) == Outcome::Truncated, "joined binary one row short");
    std::vector<TableSpec> odd = specs;
    odd[0].rows = -1;
    CHECK(outcome(odd) == Outcome::Malformed && !reserved, "joined without a row count");
    odd = specs;
    odd[3].wanted = {0, 1};
    CHECK(outcome(odd) == Outcome::Malformed, "joined with different columns");
    for (const TableSpec &s : specs) std::remove(s.path.c_str());
}

/// Random bytes and random specs: every outcome is a table or one of the reader's errors, and
/// a table always holds rows x wanted values.
void test_fuzz() {
    std::string path = temp_path("fuzz.bin");
    const char alphabet[] = "0123456789+-.eEnaifINF \t\r\n,;#/x";
    for (int i = 0; i < 400; ++i) {
        std::mt19937_64 gen(1000 + uint64_t(i));
        size_t size = gen() % 3000;
        std::string bytes(size, '\0');
        bool text = gen() % 2;
        for (char &c : bytes)
            c = text ? alphabet[gen() % (sizeof alphabet - 1)] : char(gen());
        write_file(path, bytes);
        TableSpec spec;
        spec.path = path;
        spec.offset = gen() % 64;
        spec.encoding = text ? Encoding::Ascii : Encoding(gen() % 3);
        size_t ncols = 1 + gen() % 6;
        for (size_t c = 0; c < ncols; ++c) spec.columns.push_back(Scalar(gen() % 8));
        spec.rows = int64_t(gen() % 200) - (gen() % 4 == 0 ? 300 : 0);
        if (spec.rows < 0) spec.rows = -1;
        size_t nw = gen() % (ncols + 2);
        for (size_t k = 0; k < nw; ++k) spec.wanted.push_back(uint32_t(gen() % (ncols + 1)));
        spec.exact_columns = gen() % 2;
        spec.commas = gen() % 2;
        Table t;
        Outcome o = read_one(spec, t, int(1 + gen() % 3));
        CHECK(o != Outcome::Cancelled, "fuzz case %d: cancelled", i);
        if (o == Outcome::Ok)
            CHECK(t.values.size() == t.rows * spec.wanted.size(), "fuzz case %d: %zu values", i,
                  t.values.size());
    }
    // lying row counts fail as truncated data, without reserving memory for them
    write_file(path, "1 2 3\n4 5 6\n");
    Table t;
    CHECK(read_one(ascii_spec(path, 3, int64_t(1) << 50), t) == Outcome::Truncated, "ascii 2^50");
    TableSpec bin = ascii_spec(path, 3, int64_t(1) << 60);
    bin.encoding = Encoding::BinaryLittle;
    CHECK(read_one(bin, t) == Outcome::Truncated, "binary 2^60 rows");
    std::remove(path.c_str());
    CHECK(read_one(ascii_spec(temp_path("absent"), 3, 1), t) == Outcome::Other, "missing file");
}

/// What reading a face spec gave: the faces, or the kind of error.
Outcome read_faces_of(const FaceSpec &spec, Faces &out) {
    Progress progress;
    return outcome_of([&] { read_faces(spec, out, progress); });
}

/// Appends one binary scalar of type `s` holding `v` (little- or big-endian).
void put_scalar(std::string &out, Scalar s, double v, bool big) {
    char b[8];
    size_t n = scalar_size(s);
    switch (s) {
        case Scalar::I8: { int8_t x = int8_t(v); std::memcpy(b, &x, 1); break; }
        case Scalar::U8: { uint8_t x = uint8_t(v); std::memcpy(b, &x, 1); break; }
        case Scalar::I16: { int16_t x = int16_t(v); std::memcpy(b, &x, 2); break; }
        case Scalar::U16: { uint16_t x = uint16_t(v); std::memcpy(b, &x, 2); break; }
        case Scalar::I32: { int32_t x = int32_t(v); std::memcpy(b, &x, 4); break; }
        case Scalar::U32: { uint32_t x = uint32_t(v); std::memcpy(b, &x, 4); break; }
        case Scalar::F32: { float x = float(v); std::memcpy(b, &x, 4); break; }
        case Scalar::F64: { double x = v; std::memcpy(b, &x, 8); break; }
    }
    if (big) std::reverse(b, b + n);
    out.append(b, n);
}

/// Face records of random polygons (3-7 corners, indices < nvert) with a scalar before and a
/// list after the index list, in each encoding: the fans they must give, then damaged copies.
void test_faces() {
    std::string path = temp_path("faces.ply");
    const uint32_t nvert = 50;
    for (int enc = 0; enc < 3; ++enc) {
        std::mt19937_64 gen(77 + uint64_t(enc));
        FaceSpec spec;
        spec.path = path;
        spec.encoding = Encoding(enc);
        spec.properties = {{false, Scalar::U8, Scalar::F32}, {true, Scalar::U16, Scalar::I32},
                           {true, Scalar::U8, Scalar::F64}};
        spec.indices = 1;
        spec.vertices = nvert;
        spec.faces = 200;
        const bool big = spec.encoding == Encoding::BinaryBig;
        std::string data = spec.encoding == Encoding::Ascii ? "1 2 3\n4 5 6\n" : "";
        spec.skip_lines = spec.encoding == Encoding::Ascii ? 2 : 0;
        std::vector<int32_t> want;
        uint64_t polygons = 0;
        for (uint64_t f = 0; f < spec.faces; ++f) {
            uint32_t n = 3 + uint32_t(gen() % 5);
            std::vector<int32_t> c(n);
            for (int32_t &x : c) x = int32_t(gen() % nvert);
            for (uint32_t k = 1; k + 1 < n; ++k) want.insert(want.end(), {c[0], c[k], c[k + 1]});
            polygons += n > 3;
            if (spec.encoding == Encoding::Ascii) {
                data += "0.5 " + std::to_string(n);
                for (int32_t x : c) data += " " + std::to_string(x);
                data += " 2 1.5 -2\n";
            } else {
                put_scalar(data, Scalar::F32, 0.5, big);
                put_scalar(data, Scalar::U16, n, big);
                for (int32_t x : c) put_scalar(data, Scalar::I32, x, big);
                put_scalar(data, Scalar::U8, 2, big);
                put_scalar(data, Scalar::F64, 1.5, big);
                put_scalar(data, Scalar::F64, -2, big);
            }
        }
        write_file(path, data);
        Faces got;
        CHECK(read_faces_of(spec, got) == Outcome::Ok, "faces enc %d: read", enc);
        CHECK(got.triangles == want, "faces enc %d: %zu triangle indices", enc,
              got.triangles.size());
        CHECK(got.polygons == polygons, "faces enc %d: polygons", enc);
        // cut anywhere inside the records: truncated (ASCII: a short last line), never a crash
        for (int i = 0; i < 60; ++i) {
            size_t cut = spec.skip_lines * 6 + gen() % (data.size() - spec.skip_lines * 6);
            write_file(path, data.substr(0, cut));
            Outcome o = read_faces_of(spec, got);
            CHECK(o == Outcome::Truncated || (enc == 0 && o == Outcome::Malformed),
                  "faces enc %d cut %zu: outcome %d", enc, cut, int(o));
        }
        // random bytes over the records, random specs: only the reader's own errors
        for (int i = 0; i < 200; ++i) {
            std::string bad = data;
            for (int k = 0; k < 8; ++k) bad[gen() % bad.size()] = char(gen());
            write_file(path, bad);
            FaceSpec s = spec;
            if (i % 4 == 0) s.faces = gen() % 400;
            if (i % 5 == 0) s.vertices = gen() % 60;
            if (i % 7 == 0) s.offset = gen() % 40;
            if (i % 11 == 0) s.faces = uint64_t(1) << 60;
            Outcome o = read_faces_of(s, got);
            CHECK(o != Outcome::Cancelled, "faces fuzz enc %d case %d", enc, i);
            if (o == Outcome::Ok)
                for (int32_t x : got.triangles)
                    CHECK(x >= 0 && uint64_t(x) < s.vertices, "faces fuzz: index %d", x);
        }
    }
    // a spec whose index property is not a list is refused before reading
    FaceSpec bad;
    bad.path = path;
    bad.properties = {{false, Scalar::U8, Scalar::I32}};
    Faces got;
    CHECK(read_faces_of(bad, got) == Outcome::Other, "faces: scalar index property");
    std::remove(path.c_str());
}

/// An OBJ file's fans and negative indices, then random text: the reader's own errors only,
/// and every index it returns names a vertex.
void test_obj() {
    std::string path = temp_path("mesh.obj");
    write_file(path, "# c\nv 0 0 0\nv 1 0 0 0.5 0.25 1\nvt 0 0\nv 1 1 0\nv 0 1 0\n"
                     "f 1/1 2/1/1 3//1 4\ng x\nf -4 -3 -2\nl 1 2\n");
    Progress progress;
    ObjMesh m = read_obj(path, progress);
    CHECK(m.vertices.size() == 12 && m.colors.empty(), "obj: %zu values", m.vertices.size());
    CHECK((m.triangles == std::vector<int32_t>{0, 1, 2, 0, 2, 3, 0, 1, 2}), "obj: triangles");
    CHECK(m.polygons == 1, "obj: polygons");
    const char alphabet[] = "vf0123456789 -/.\n#e";
    for (int i = 0; i < 400; ++i) {
        std::mt19937_64 gen(5000 + uint64_t(i));
        std::string text(gen() % 400, ' ');
        for (char &c : text) c = alphabet[gen() % (sizeof alphabet - 1)];
        write_file(path, text);
        ObjMesh got;
        Outcome o = outcome_of([&] {
            Progress pr;
            got = read_obj(path, pr);
        });
        CHECK(o == Outcome::Ok || o == Outcome::Malformed, "obj fuzz %d: outcome %d", i, int(o));
        for (int32_t x : got.triangles)
            CHECK(x >= 0 && size_t(x) < got.vertices.size() / 3, "obj fuzz %d: index %d", i, x);
    }
    std::remove(path.c_str());
}

/// Expands `stream` into `size` bytes: the bytes, or "!" + the error's kind when it throws.
std::string lzf(const std::vector<uint8_t> &stream, size_t size) {
    std::vector<uint8_t> out(size);
    try {
        lzf_decompress(stream.data(), stream.size(), out.data(), size);
    } catch (const MalformedData &) {
        return "!malformed";
    }
    return std::string(out.begin(), out.end());
}

void test_lzf() {
    // literal runs: control byte c < 32, then c + 1 bytes
    CHECK(lzf({2, 'a', 'b', 'c'}, 3) == "abc", "literal run");
    CHECK(lzf({0, 'a', 1, 'b', 'c'}, 3) == "abc", "two literal runs");
    CHECK(lzf({}, 0).empty(), "empty stream, empty data");
    // a back reference: length - 2 in the top three bits, offset - 1 in 13 bits; overlapping
    // copies repeat the pattern ("ab" then 6 bytes from 2 back)
    CHECK(lzf({1, 'a', 'b', (6 - 2) << 5, 1}, 8) == "abababab", "overlapping back reference");
    CHECK(lzf({3, 'w', 'x', 'y', 'z', (3 - 2) << 5, 3}, 7) == "wxyzwxy", "back reference");
    // length 7 + the next byte: 2 + 7 + 20 = 29 copies of one byte
    CHECK(lzf({0, 'q', 7 << 5, 20, 0}, 30) == std::string(30, 'q'), "long back reference");
    // the largest offset, 8192 back, over a literal block of 8192 bytes
    std::vector<uint8_t> big;
    std::string want;
    for (int run = 0; run < 256; ++run) {
        big.push_back(31);
        for (int k = 0; k < 32; ++k) {
            big.push_back(uint8_t(run * 7 + k));
            want.push_back(char(uint8_t(run * 7 + k)));
        }
    }
    big.insert(big.end(), {uint8_t((1 << 5) | 31), 0xff});  // 3 bytes from 8192 back
    want += want.substr(0, 3);
    CHECK(lzf(big, want.size()) == want, "offset 8192");
    // damaged streams end in MalformedData
    CHECK(lzf({1, 'a', (6 - 2) << 5, 1}, 8) == "!malformed", "reference before the start");
    CHECK(lzf({3, 'a', 'b'}, 4) == "!malformed", "literal run past the end of the stream");
    CHECK(lzf({0, 'a', 7 << 5}, 10) == "!malformed", "long reference cut off");
    CHECK(lzf({0, 'a', 1 << 5}, 10) == "!malformed", "reference cut off");
    CHECK(lzf({2, 'a', 'b', 'c'}, 2) == "!malformed", "more bytes than declared");
    CHECK(lzf({2, 'a', 'b', 'c'}, 4) == "!malformed", "fewer bytes than declared");
    CHECK(lzf({0, 'a', (6 - 2) << 5, 0}, 4) == "!malformed", "reference past the declared size");
    // random streams: expanded or rejected, never a read or write outside the buffers (ASan)
    int ok = 0;
    for (int i = 0; i < 3000; ++i) {
        std::mt19937 gen{uint32_t(i)};
        std::vector<uint8_t> stream(gen() % 64);
        for (uint8_t &b : stream) b = uint8_t(gen());
        if (lzf(stream, gen() % 200) != "!malformed") ++ok;
    }
    CHECK(ok < 3000, "random streams: %d of 3000 expanded", ok);
}

}  // namespace

int main() {
    test_lzf();
    test_parse_number();
    test_decode_scalar();
    test_ascii_round_trip();
    test_ascii_errors_name_the_first_bad_row();
    test_text_tables_skip_blank_and_comment_lines();
    test_binary_round_trip_both_endians();
    test_several_files();
    test_joined_files();
    test_fuzz();
    test_faces();
    test_obj();
    std::printf("reader_tests: %d checks, %d failures\n", pointviz_tests::g_checks, pointviz_tests::g_failures);
    return pointviz_tests::g_failures == 0 ? 0 : 1;
}
