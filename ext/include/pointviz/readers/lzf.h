// pointviz — LZF decompression: the block format of liblzf, which PCL's binary_compressed PCD
// files hold (their readers: pointviz/readers/pcd.py). A stream is a sequence of
//   literal runs:     a control byte c < 32, then c + 1 bytes copied as they are;
//   back references:  a control byte c >= 32 whose top three bits are the length L - 2 (7: one
//                     more byte adds to L), and 13 bits of offset (c's low five and the next
//                     byte) to copy L bytes from, counted back from the output's end, minus one.
// The output is checked at every step against both buffers: a damaged or crafted stream ends in
// MalformedData, never in a read or write outside them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>

#include "pointviz/readers/table.h"

namespace pointviz {

/// Decompresses the LZF stream `in` (`in_size` bytes) into exactly `out_size` bytes at `out`.
/// Throws MalformedData if the stream runs past its own end, refers back before the output's
/// start, or expands to more or fewer than `out_size` bytes.
inline void lzf_decompress(const uint8_t *in, size_t in_size, uint8_t *out, size_t out_size) {
    size_t ip = 0, op = 0;
    while (ip < in_size) {
        const unsigned ctrl = in[ip++];
        if (ctrl < 32) {
            const size_t len = size_t(ctrl) + 1;
            if (len > in_size - ip)
                throw MalformedData("LZF: a literal run goes past the end of the compressed data");
            if (len > out_size - op)
                throw MalformedData("LZF: the data expands beyond the size it declares");
            std::memcpy(out + op, in + ip, len);
            ip += len;
            op += len;
            continue;
        }
        size_t len = ctrl >> 5;
        if (len == 7) {
            if (ip >= in_size)
                throw MalformedData("LZF: a back reference is cut off by the end of the data");
            len += in[ip++];
        }
        if (ip >= in_size)
            throw MalformedData("LZF: a back reference is cut off by the end of the data");
        const size_t back = ((size_t(ctrl & 31u) << 8) | in[ip++]) + 1;
        len += 2;
        if (back > op)
            throw MalformedData("LZF: a back reference points before the start of the data");
        if (len > out_size - op)
            throw MalformedData("LZF: the data expands beyond the size it declares");
        uint8_t *dst = out + op;
        const uint8_t *src = dst - back;
        if (back >= len) {
            std::memcpy(dst, src, len);
        } else {  // the copy overlaps what it writes: a repeated pattern, byte by byte
            for (size_t k = 0; k < len; ++k) dst[k] = src[k];
        }
        op += len;
    }
    if (op != out_size) throw MalformedData("LZF: the data expands to fewer bytes than it declares");
}

}  // namespace pointviz
