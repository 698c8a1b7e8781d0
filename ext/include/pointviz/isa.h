// pointviz — the instruction set a translation unit is compiled for.
//
// The traversal kernels are compiled once per instruction set (ext/src/query_kernels.cpp with
// -msse4.2, -mavx2 -mfma, -mavx512f ...; see ext/CMakeLists.txt) and chosen at run time
// (dispatch.h). Every inline function the kernels use lives in the inline namespace named
// here, so that the copies compiled for different instruction sets have different symbols and
// the linker never hands an AVX2 copy to a caller on a CPU without AVX2. Plain data types stay
// outside it: they are the same in every unit.
#pragma once

#ifndef POINTVIZ_ISA_NS
#define POINTVIZ_ISA_NS isa_base
#endif

#define POINTVIZ_ISA_BEGIN inline namespace POINTVIZ_ISA_NS {
#define POINTVIZ_ISA_END }
