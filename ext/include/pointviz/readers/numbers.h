// pointviz — numbers in text and in binary rows: the token scanner and the scalar decoder that
// every table reader (PLY, PCD, XYZ) shares. Header-only so that tests reach each piece.
#pragma once

#include <charconv>
#include <cstdint>
#include <cstring>
#include <limits>
#include <system_error>

namespace pointviz {

/// Scalar types a binary row may hold (PLY and PCD types map here).
enum class Scalar : uint8_t { I8, U8, I16, U16, I32, U32, F32, F64 };

/// Bytes of one scalar.
inline size_t scalar_size(Scalar s) {
    switch (s) {
        case Scalar::I8: case Scalar::U8: return 1;
        case Scalar::I16: case Scalar::U16: return 2;
        case Scalar::I32: case Scalar::U32: case Scalar::F32: return 4;
        case Scalar::F64: return 8;
    }
    return 0;
}

/// One T at `p` (unaligned), bytes reversed when `swap`; a fixed-size memcpy compiles to a load.
template <class T>
inline double load_scalar(const char *p, bool swap) {
    T v;
    if (!swap) {
        std::memcpy(&v, p, sizeof(T));
    } else {
        char b[sizeof(T)];
        for (size_t i = 0; i < sizeof(T); ++i) b[i] = p[sizeof(T) - 1 - i];
        std::memcpy(&v, b, sizeof(T));
    }
    return double(v);
}

/// Decodes one scalar at `p` (unaligned), swapping bytes when `swap` (big-endian data).
inline double decode_scalar(const char *p, Scalar s, bool swap) {
    switch (s) {
        case Scalar::I8: return load_scalar<int8_t>(p, swap);
        case Scalar::U8: return load_scalar<uint8_t>(p, swap);
        case Scalar::I16: return load_scalar<int16_t>(p, swap);
        case Scalar::U16: return load_scalar<uint16_t>(p, swap);
        case Scalar::I32: return load_scalar<int32_t>(p, swap);
        case Scalar::U32: return load_scalar<uint32_t>(p, swap);
        case Scalar::F32: return load_scalar<float>(p, swap);
        case Scalar::F64: return load_scalar<double>(p, swap);
    }
    return 0.0;
}

/// Whether `c` separates tokens on a line: blanks always, commas and semicolons when `commas`
/// (XYZ-style text is written with either).
inline bool is_separator(char c, bool commas) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f' ||
           (commas && (c == ',' || c == ';'));
}

/// The exact (Clinger) fast path of decimal parsing: a token of at most 15 significant digits
/// ("-0.0570643", "12", "3.5e-3") is m * 10^k with m and 10^|k| exact doubles (m < 2^53,
/// |k| <= 22), so one multiplication or division rounds it correctly: the same double that
/// from_chars gives, several times faster. Returns false (nothing parsed) for anything else.
inline bool parse_simple_decimal(const char *b, const char *e, double &out) {
    static constexpr double kPow10[] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                        1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                        1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
    constexpr int kMaxDigits = 15;  // 10^15 < 2^53: the mantissa is exact
    uint64_t m = 0;
    int digits = 0, scale = 0;
    const char *p = b;
    bool any = false;
    for (; p != e && unsigned(*p - '0') < 10; ++p, any = true) {
        if (m == 0 && *p == '0') continue;  // leading zeros do not count
        if (++digits > kMaxDigits) return false;
        m = m * 10 + uint64_t(*p - '0');
    }
    if (p != e && *p == '.') {
        for (++p; p != e && unsigned(*p - '0') < 10; ++p, any = true) {
            --scale;
            if (m == 0 && *p == '0') continue;
            if (++digits > kMaxDigits) return false;
            m = m * 10 + uint64_t(*p - '0');
        }
    }
    if (!any) return false;
    if (p != e && (*p == 'e' || *p == 'E')) {
        ++p;
        bool eneg = false;
        if (p != e && (*p == '+' || *p == '-')) eneg = *p++ == '-';
        if (p == e) return false;
        int x = 0;
        for (; p != e && unsigned(*p - '0') < 10; ++p) {
            if (x > 1000) return false;  // far out of the fast path's range
            x = x * 10 + (*p - '0');
        }
        scale += eneg ? -x : x;
    }
    if (p != e) return false;
    if (m == 0) {
        out = 0.0;
        return true;
    }
    if (scale < -22 || scale > 22) return false;
    out = scale < 0 ? double(m) / kPow10[-scale] : double(m) * kPow10[scale];
    return true;
}

/// Parses the whole token [b, e) as a number: decimal or scientific, optional sign, "nan",
/// "inf"/"infinity" (any case). Values beyond the double range become +-inf, as in strtod.
/// Returns false when the token is not entirely a number.
inline bool parse_number(const char *b, const char *e, double &out) {
    if (b == e) return false;
    bool neg = false;
    if (*b == '+' || *b == '-') {
        neg = *b == '-';
        ++b;
        if (b == e || *b == '+' || *b == '-') return false;  // from_chars would take "--1"
    }
    double v = 0.0;
    if (parse_simple_decimal(b, e, v)) {
        out = neg ? -v : v;
        return true;
    }
    auto r = std::from_chars(b, e, v, std::chars_format::general);
    if (r.ptr != e) return false;
    if (r.ec == std::errc::result_out_of_range) {
        // from_chars leaves v untouched: decide overflow or underflow from the exponent's sign
        const char *x = b;
        while (x != e && *x != 'e' && *x != 'E') ++x;
        bool tiny = x != e && x + 1 != e && x[1] == '-';
        v = tiny ? 0.0 : std::numeric_limits<double>::infinity();
    } else if (r.ec != std::errc()) {
        return false;
    }
    out = neg ? -v : v;
    return true;
}

}  // namespace pointviz
