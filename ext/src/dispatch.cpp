// pointviz — run-time choice of the traversal kernels, and the public batch queries.
#include "pointviz/dispatch.h"

#include <stdexcept>
#include <string>

namespace pointviz {

// One table per instruction set this build compiled (cast.cpp).
const QueryKernels &kernels_base();
#if defined(POINTVIZ_HAVE_SSE42)
const QueryKernels &kernels_sse42();
#endif
#if defined(POINTVIZ_HAVE_AVX2)
const QueryKernels &kernels_avx2();
#endif
#if defined(POINTVIZ_HAVE_AVX512)
const QueryKernels &kernels_avx512();
#endif

namespace {

/// The table of `isa`, or null when this build or this CPU lacks it.
const QueryKernels *find_kernels(Isa isa) {
    switch (isa) {
        case Isa::Auto:
        case Isa::Base: return &kernels_base();
#if defined(POINTVIZ_HAVE_SSE42)
        case Isa::Sse42:
            return __builtin_cpu_supports("sse4.2") && __builtin_cpu_supports("popcnt")
                       ? &kernels_sse42() : nullptr;
#endif
#if defined(POINTVIZ_HAVE_AVX2)
        case Isa::Avx2:
            return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")
                       ? &kernels_avx2() : nullptr;
#endif
#if defined(POINTVIZ_HAVE_AVX512)
        case Isa::Avx512:
            return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") &&
                           __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
                           __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq")
                       ? &kernels_avx512() : nullptr;
#endif
        default: return nullptr;
    }
}

}  // namespace

bool isa_available(Isa isa) { return find_kernels(isa) != nullptr; }

Isa best_isa() {
    // The CPU does not change while the process runs: decided once.
    static const Isa best = [] {
        for (Isa isa : {Isa::Avx512, Isa::Avx2, Isa::Sse42})
            if (isa_available(isa)) return isa;
        return Isa::Base;
    }();
    return best;
}

std::vector<Isa> available_isas() {
    std::vector<Isa> out;
    for (Isa isa : {Isa::Base, Isa::Sse42, Isa::Avx2, Isa::Avx512})
        if (isa_available(isa)) out.push_back(isa);
    return out;
}

const char *isa_name(Isa isa) {
    switch (isa) {
        case Isa::Auto: return "auto";
        case Isa::Base: return "base";
        case Isa::Sse42: return "sse4.2";
        case Isa::Avx2: return "avx2";
        case Isa::Avx512: return "avx512";
    }
    return "unknown";
}

const QueryKernels &query_kernels(Isa isa) {
    const QueryKernels *k = find_kernels(isa == Isa::Auto ? best_isa() : isa);
    if (!k)
        throw std::invalid_argument(std::string("isa: ") + isa_name(isa) +
                                    " kernels are not available on this CPU or in this build");
    return *k;
}

namespace {

/// Whether a batch of closest or any hits goes to the packet kernels (packet_cast.h): asked for, no
/// statistics, and the wide traversal serves it.
bool by_packets(const SurfelTree &tree, const TraceOptions &opt, bool count) {
    return opt.packets && !count && use_wide(tree, opt);
}

void cast_with(const QueryKernels &k, const SurfelTree &tree, const float *rays, size_t n,
               const TraceOptions &opt, float pixel_angle, int threads, CastOutput out,
               bool count, BatchStats &stats) {
    if (by_packets(tree, opt, count) &&
        k.cast_packets_f32(tree, rays, n, opt, pixel_angle, threads, out, count, stats))
        return;
    k.cast_f32(tree, rays, n, opt, pixel_angle, threads, out, count, stats);
}
void cast_with(const QueryKernels &k, const SurfelTree &tree, const double *rays, size_t n,
               const TraceOptions &opt, float pixel_angle, int threads, CastOutput out,
               bool count, BatchStats &stats) {
    if (by_packets(tree, opt, count) &&
        k.cast_packets_f64(tree, rays, n, opt, pixel_angle, threads, out, count, stats))
        return;
    k.cast_f64(tree, rays, n, opt, pixel_angle, threads, out, count, stats);
}
void occluded_with(const QueryKernels &k, const SurfelTree &tree, const float *rays,
                   const float *t_max, size_t n, const TraceOptions &opt, float t_min,
                   float pixel_angle, int threads, uint8_t *hit, bool count, BatchStats &stats) {
    if (by_packets(tree, opt, count) &&
        k.occluded_packets_f32(tree, rays, t_max, n, opt, t_min, pixel_angle, threads, hit, count,
                               stats))
        return;
    k.occluded_f32(tree, rays, t_max, n, opt, t_min, pixel_angle, threads, hit, count, stats);
}
void occluded_with(const QueryKernels &k, const SurfelTree &tree, const double *rays,
                   const float *t_max, size_t n, const TraceOptions &opt, float t_min,
                   float pixel_angle, int threads, uint8_t *hit, bool count, BatchStats &stats) {
    if (by_packets(tree, opt, count) &&
        k.occluded_packets_f64(tree, rays, t_max, n, opt, t_min, pixel_angle, threads, hit, count,
                               stats))
        return;
    k.occluded_f64(tree, rays, t_max, n, opt, t_min, pixel_angle, threads, hit, count, stats);
}

}  // namespace

template <class T>
void cast_rays(const SurfelTree &tree, const T *rays, size_t n, const TraceOptions &opt,
               float pixel_angle, int threads, CastOutput out, bool count, BatchStats &stats) {
    cast_with(query_kernels(opt.isa), tree, rays, n, opt, pixel_angle, threads, out, count, stats);
}

template <class T>
void occluded(const SurfelTree &tree, const T *rays, const float *t_max, size_t n,
              const TraceOptions &opt, float t_min, float pixel_angle, int threads, uint8_t *hit,
              bool count, BatchStats &stats) {
    occluded_with(query_kernels(opt.isa), tree, rays, t_max, n, opt, t_min, pixel_angle, threads,
                  hit, count, stats);
}

template void cast_rays<float>(const SurfelTree &, const float *, size_t, const TraceOptions &,
                               float, int, CastOutput, bool, BatchStats &);
template void cast_rays<double>(const SurfelTree &, const double *, size_t, const TraceOptions &,
                                float, int, CastOutput, bool, BatchStats &);
template void occluded<float>(const SurfelTree &, const float *, const float *, size_t,
                              const TraceOptions &, float, float, int, uint8_t *, bool, BatchStats &);
template void occluded<double>(const SurfelTree &, const double *, const float *, size_t,
                               const TraceOptions &, float, float, int, uint8_t *, bool, BatchStats &);

}  // namespace pointviz
