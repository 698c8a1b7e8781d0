// pointviz — choosing the traversal kernels at run time: one build runs on any x86-64 CPU and
// uses AVX2 or AVX-512 where the CPU has them. The kernels of each instruction set are the same
// sources (ext/src/cast.cpp, ext/src/packet_cast.cpp) compiled with that set's flags (isa.h, ext/CMakeLists.txt).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/cast.h"
#include "pointviz/isa.h"

namespace pointviz {

/// The batch queries of one instruction set.
struct QueryKernels {
    Isa isa;
    const char *name;
    void (*cast_f32)(const SurfelTree &, const float *, size_t, const TraceOptions &, float, int,
                     CastOutput, bool, BatchStats &);
    void (*cast_f64)(const SurfelTree &, const double *, size_t, const TraceOptions &, float, int,
                     CastOutput, bool, BatchStats &);
    void (*occluded_f32)(const SurfelTree &, const float *, const float *, size_t,
                         const TraceOptions &, float, float, int, uint8_t *, bool, BatchStats &);
    void (*occluded_f64)(const SurfelTree &, const double *, const float *, size_t,
                         const TraceOptions &, float, float, int, uint8_t *, bool, BatchStats &);
    /// cast_f32 / cast_f64 without statistics, coherent groups of rays as packets
    /// (packet_cast.h; the wide traversal only). false: not done, the batch is not coherent.
    bool (*cast_packets_f32)(const SurfelTree &, const float *, size_t, const TraceOptions &,
                             float, int, CastOutput, bool, BatchStats &);
    bool (*cast_packets_f64)(const SurfelTree &, const double *, size_t, const TraceOptions &,
                             float, int, CastOutput, bool, BatchStats &);
    /// occluded_f32 / occluded_f64 the same way (packet_cast.h).
    bool (*occluded_packets_f32)(const SurfelTree &, const float *, const float *, size_t,
                                 const TraceOptions &, float, float, int, uint8_t *, bool,
                                 BatchStats &);
    bool (*occluded_packets_f64)(const SurfelTree &, const double *, const float *, size_t,
                                 const TraceOptions &, float, float, int, uint8_t *, bool,
                                 BatchStats &);
    /// Closest hits of local rays shifted by `offset` (the renderer's batches; one thread).
    void (*intersect)(const SurfelTree &, const Ray *, size_t, Vec3 offset, const TraceOptions &,
                      SurfaceHit *);
    /// Any hits of local rays shifted by `offset`, two-sided (shadow rays; one thread).
    void (*occlude)(const SurfelTree &, const Ray *, size_t, Vec3 offset, const TraceOptions &,
                    uint8_t *);
};

/// Whether this build has kernels for `isa` and this CPU runs them (Auto, Base: always).
bool isa_available(Isa isa);
/// The best instruction set available.
Isa best_isa();
/// Every instruction set available, Base first.
std::vector<Isa> available_isas();
/// Short name: "auto", "base", "sse4.2", "avx2", "avx512".
const char *isa_name(Isa isa);
/// The kernels for `isa` (Auto: best_isa()). Throws std::invalid_argument when unavailable.
const QueryKernels &query_kernels(Isa isa);

}  // namespace pointviz
