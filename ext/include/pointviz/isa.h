// pointviz — the instruction set a translation unit is compiled for, and the run-time choice.
//
// The traversal kernels (ext/src/cast.cpp) are compiled once per instruction set (-msse4.2,
// -mavx2 -mfma, -mavx512f ...; see ext/CMakeLists.txt) and chosen at run time (dispatch.h), so
// one build runs on any x86-64 CPU and is fast on this one. Every inline function the kernels
// use lives in the inline namespace named here, so that the copies compiled for different
// instruction sets have different symbols and the linker never hands an AVX2 copy to a caller
// on a CPU without AVX2. Plain data types stay outside it: they are the same in every unit.
#pragma once

#include <cstdint>

#ifndef POINTVIZ_ISA_NS
#define POINTVIZ_ISA_NS isa_base
#endif

#define POINTVIZ_ISA_BEGIN inline namespace POINTVIZ_ISA_NS {
#define POINTVIZ_ISA_END }

namespace pointviz {

/// Instruction set of the traversal kernels (dispatch.h). Every one gives the same results,
/// bit for bit (the build turns floating-point contraction off).
enum class Isa : uint8_t {
    Auto = 0,    ///< the best one this CPU runs
    Base = 1,    ///< the portable build (x86-64: SSE2), disks tested one at a time
    Sse42 = 2,   ///< SSE4.2 and POPCNT
    Avx2 = 3,    ///< AVX2 and FMA: the disks of a leaf eight at a time
    Avx512 = 4,  ///< AVX-512 F/VL/BW/DQ on top of AVX2
};

}  // namespace pointviz
