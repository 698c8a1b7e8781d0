// Embree 3 baseline for the pointviz benchmarks: oriented discs and triangles behind one C API.
//
// The library is compiled on demand by benchmarks/_baselines.py and loaded with ctypes. It exists
// so that pointviz's surfel tracer can be compared with the fairest available point baseline,
// Embree's RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT (the same disc model: centre, normal, radius),
// and with Embree triangles on the source mesh, all timed by the same harness, the same rays and
// the same thread count.
//
// Threads: the device is created with the config string "threads=N" (Embree's own build threads),
// and queries are split over N std::threads that pull fixed-size chunks of rays from an atomic
// counter. Every ray is independent, so results do not depend on the schedule.
//
// Query modes: 1 = rtcIntersect1/rtcOccluded1 per ray; 4, 8, 16 = packets of that many
// consecutive rays (rtcIntersect4/8/16, coherent context flag). The harness measures the modes and
// reports the fastest.
//
// Memory: rtcSetDeviceMemoryMonitorFunction tracks every byte Embree allocates; the handle
// reports the peak during the build and the bytes still held after it (the BVH), both relative to
// the device's allocation before the build. The input buffers are owned by this library (copied,
// padded as Embree requires) and reported separately as input_bytes.

#include <embree3/rtcore.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <thread>
#include <vector>

namespace {

// Rays handed to one worker at a time. A multiple of 16 so that packets never straddle chunks;
// large enough that the atomic counter is negligible, small enough to balance incoherent rays.
constexpr long long kChunkRays = 4096;

// Embree reads vertex buffers with 16-byte loads, so the last element must be followed by
// readable memory: pad every shared buffer by this many floats.
constexpr size_t kBufferPadFloats = 4;

constexpr int kOk = 0;
constexpr int kError = 1;

struct Handle {
    RTCDevice device = nullptr;
    RTCScene scene = nullptr;
    int threads = 1;
    std::atomic<long long> current_bytes{0};
    std::atomic<long long> peak_bytes{0};
    std::vector<float> vertices;     // discs: x y z r per point; triangles: x y z per vertex
    std::vector<float> normals;      // discs: nx ny nz per point
    std::vector<uint32_t> indices;   // triangles: i j k per face
    long long input_bytes = 0;
    long long primitives = 0;
    double build_seconds = 0.0;
    long long build_peak_bytes = 0;
    long long scene_bytes = 0;
    std::string error;
};

bool memory_monitor(void* user, ssize_t bytes, bool /*post*/) {
    // Called with bytes > 0 before an allocation and bytes < 0 after a release (or after a failed
    // allocation), so the running sum is the live total; the peak is kept lock-free.
    auto* h = static_cast<Handle*>(user);
    const long long now = h->current_bytes.fetch_add(static_cast<long long>(bytes)) + bytes;
    long long prev = h->peak_bytes.load();
    while (now > prev && !h->peak_bytes.compare_exchange_weak(prev, now)) {
    }
    return true;
}

void error_function(void* user, RTCError code, const char* message) {
    auto* h = static_cast<Handle*>(user);
    char buffer[64];
    std::snprintf(buffer, sizeof(buffer), "embree error %d: ", static_cast<int>(code));
    h->error = std::string(buffer) + (message ? message : "");
}

void copy_error(const Handle* h, char* out, int out_len) {
    if (out && out_len > 0) {
        std::snprintf(out, static_cast<size_t>(out_len), "%s", h->error.c_str());
    }
}

// Runs body(begin, end) over [0, n) in kChunkRays chunks on `threads` std::threads.
template <class Body>
void parallel_chunks(long long n, int threads, Body body) {
    std::atomic<long long> next{0};
    auto worker = [&]() {
        for (;;) {
            const long long begin = next.fetch_add(kChunkRays);
            if (begin >= n) return;
            body(begin, std::min(n, begin + kChunkRays));
        }
    };
    const long long useful = (n + kChunkRays - 1) / kChunkRays;
    const int count = static_cast<int>(std::max(1LL, std::min<long long>(threads, useful)));
    std::vector<std::thread> pool;
    pool.reserve(count - 1);
    for (int i = 1; i < count; ++i) pool.emplace_back(worker);
    worker();
    for (auto& t : pool) t.join();
}

void init_context(RTCIntersectContext* ctx, bool coherent) {
    rtcInitIntersectContext(ctx);
    ctx->flags = coherent ? RTC_INTERSECT_CONTEXT_FLAG_COHERENT : RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
}

void write_hit(long long i, float tfar, unsigned geom, unsigned prim, float nx, float ny, float nz,
               float* t_out, int32_t* prim_out, float* ng_out) {
    if (geom == RTC_INVALID_GEOMETRY_ID) {
        t_out[i] = std::numeric_limits<float>::infinity();
        if (prim_out) prim_out[i] = -1;
        if (ng_out) ng_out[3 * i] = ng_out[3 * i + 1] = ng_out[3 * i + 2] = 0.0f;
        return;
    }
    t_out[i] = tfar;
    if (prim_out) prim_out[i] = static_cast<int32_t>(prim);
    if (ng_out) {
        const float len = std::sqrt(nx * nx + ny * ny + nz * nz);
        const float inv = len > 0.0f ? 1.0f / len : 0.0f;
        ng_out[3 * i] = nx * inv;
        ng_out[3 * i + 1] = ny * inv;
        ng_out[3 * i + 2] = nz * inv;
    }
}

void intersect_single(const Handle* h, const float* rays, long long begin, long long end,
                      float tnear, float tfar, float* t_out, int32_t* prim_out, float* ng_out) {
    RTCIntersectContext ctx;
    init_context(&ctx, false);
    for (long long i = begin; i < end; ++i) {
        const float* r = rays + 6 * i;
        RTCRayHit rh;
        rh.ray.org_x = r[0]; rh.ray.org_y = r[1]; rh.ray.org_z = r[2];
        rh.ray.dir_x = r[3]; rh.ray.dir_y = r[4]; rh.ray.dir_z = r[5];
        rh.ray.tnear = tnear;
        rh.ray.tfar = tfar;
        rh.ray.time = 0.0f;
        rh.ray.mask = 0xFFFFFFFFu;
        rh.ray.id = static_cast<unsigned>(i);
        rh.ray.flags = 0;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(h->scene, &ctx, &rh);
        write_hit(i, rh.ray.tfar, rh.hit.geomID, rh.hit.primID, rh.hit.Ng_x, rh.hit.Ng_y,
                  rh.hit.Ng_z, t_out, prim_out, ng_out);
    }
}

void occluded_single(const Handle* h, const float* rays, long long begin, long long end,
                     float tnear, const float* tmax, uint8_t* out) {
    RTCIntersectContext ctx;
    init_context(&ctx, false);
    for (long long i = begin; i < end; ++i) {
        const float* r = rays + 6 * i;
        RTCRay ray;
        ray.org_x = r[0]; ray.org_y = r[1]; ray.org_z = r[2];
        ray.dir_x = r[3]; ray.dir_y = r[4]; ray.dir_z = r[5];
        ray.tnear = tnear;
        ray.tfar = tmax[i];
        ray.time = 0.0f;
        ray.mask = 0xFFFFFFFFu;
        ray.id = static_cast<unsigned>(i);
        ray.flags = 0;
        rtcOccluded1(h->scene, &ctx, &ray);
        out[i] = ray.tfar < 0.0f ? 1 : 0;  // Embree sets tfar = -inf on occlusion
    }
}

template <int N> struct Packet;
template <> struct Packet<4> {
    using RayHit = RTCRayHit4;
    using Ray = RTCRay4;
    static void intersect(const int* v, RTCScene s, RTCIntersectContext* c, RayHit* r) { rtcIntersect4(v, s, c, r); }
    static void occluded(const int* v, RTCScene s, RTCIntersectContext* c, Ray* r) { rtcOccluded4(v, s, c, r); }
};
template <> struct Packet<8> {
    using RayHit = RTCRayHit8;
    using Ray = RTCRay8;
    static void intersect(const int* v, RTCScene s, RTCIntersectContext* c, RayHit* r) { rtcIntersect8(v, s, c, r); }
    static void occluded(const int* v, RTCScene s, RTCIntersectContext* c, Ray* r) { rtcOccluded8(v, s, c, r); }
};
template <> struct Packet<16> {
    using RayHit = RTCRayHit16;
    using Ray = RTCRay16;
    static void intersect(const int* v, RTCScene s, RTCIntersectContext* c, RayHit* r) { rtcIntersect16(v, s, c, r); }
    static void occluded(const int* v, RTCScene s, RTCIntersectContext* c, Ray* r) { rtcOccluded16(v, s, c, r); }
};

template <int N, class R>
void fill_packet_ray(R& ray, const float* rays, long long base, int count, float tnear,
                     const float* tmax, float tfar, int* valid) {
    for (int k = 0; k < N; ++k) {
        const bool active = k < count;
        const float* r = rays + 6 * (base + (active ? k : 0));
        valid[k] = active ? -1 : 0;
        ray.org_x[k] = r[0]; ray.org_y[k] = r[1]; ray.org_z[k] = r[2];
        ray.dir_x[k] = r[3]; ray.dir_y[k] = r[4]; ray.dir_z[k] = r[5];
        ray.tnear[k] = tnear;
        ray.tfar[k] = tmax ? tmax[base + (active ? k : 0)] : tfar;
        ray.time[k] = 0.0f;
        ray.mask[k] = 0xFFFFFFFFu;
        ray.id[k] = static_cast<unsigned>(base + k);
        ray.flags[k] = 0;
    }
}

template <int N>
void intersect_packets(const Handle* h, const float* rays, long long begin, long long end,
                       float tnear, float tfar, float* t_out, int32_t* prim_out, float* ng_out) {
    RTCIntersectContext ctx;
    init_context(&ctx, true);
    alignas(64) typename Packet<N>::RayHit rh;
    alignas(64) int valid[N];
    for (long long base = begin; base < end; base += N) {
        const int count = static_cast<int>(std::min<long long>(N, end - base));
        fill_packet_ray<N>(rh.ray, rays, base, count, tnear, nullptr, tfar, valid);
        for (int k = 0; k < N; ++k) {
            rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        }
        Packet<N>::intersect(valid, h->scene, &ctx, &rh);
        for (int k = 0; k < count; ++k) {
            write_hit(base + k, rh.ray.tfar[k], rh.hit.geomID[k], rh.hit.primID[k], rh.hit.Ng_x[k],
                      rh.hit.Ng_y[k], rh.hit.Ng_z[k], t_out, prim_out, ng_out);
        }
    }
}

template <int N>
void occluded_packets(const Handle* h, const float* rays, long long begin, long long end,
                      float tnear, const float* tmax, uint8_t* out) {
    RTCIntersectContext ctx;
    init_context(&ctx, true);
    alignas(64) typename Packet<N>::Ray ray;
    alignas(64) int valid[N];
    for (long long base = begin; base < end; base += N) {
        const int count = static_cast<int>(std::min<long long>(N, end - base));
        fill_packet_ray<N>(ray, rays, base, count, tnear, tmax, 0.0f, valid);
        Packet<N>::occluded(valid, h->scene, &ctx, &ray);
        for (int k = 0; k < count; ++k) out[base + k] = ray.tfar[k] < 0.0f ? 1 : 0;
    }
}

// Intersection/occlusion filter that turns Embree's two-sided discs into one-sided ones: a hit is
// rejected when the ray arrives from behind (dir . Ng > 0; Embree's disc Ng is the given normal).
// Used to match renderers that cull back-facing surfels.
void one_sided_filter(const RTCFilterFunctionNArguments* args) {
    const unsigned n = args->N;
    for (unsigned i = 0; i < n; ++i) {
        if (args->valid[i] != -1) continue;
        const float dot = RTCRayN_dir_x(args->ray, n, i) * RTCHitN_Ng_x(args->hit, n, i) +
                          RTCRayN_dir_y(args->ray, n, i) * RTCHitN_Ng_y(args->hit, n, i) +
                          RTCRayN_dir_z(args->ray, n, i) * RTCHitN_Ng_z(args->hit, n, i);
        if (dot > 0.0f) args->valid[i] = 0;
    }
}

bool valid_mode(int mode) { return mode == 1 || mode == 4 || mode == 8 || mode == 16; }

RTCBuildQuality to_quality(int quality) {
    // 0 = low, 1 = medium, 2 = high (Embree's enum values are the same, kept explicit).
    switch (quality) {
        case 0: return RTC_BUILD_QUALITY_LOW;
        case 2: return RTC_BUILD_QUALITY_HIGH;
        default: return RTC_BUILD_QUALITY_MEDIUM;
    }
}

// Commits `geometry` into a fresh scene, timing and measuring the build.
int commit_scene(Handle* h, RTCGeometry geometry, int quality, int scene_flags,
                 std::chrono::steady_clock::time_point start, long long baseline) {
    rtcSetGeometryBuildQuality(geometry, to_quality(quality));
    rtcCommitGeometry(geometry);
    h->scene = rtcNewScene(h->device);
    rtcSetSceneBuildQuality(h->scene, to_quality(quality));
    rtcSetSceneFlags(h->scene, static_cast<RTCSceneFlags>(scene_flags));
    rtcAttachGeometry(h->scene, geometry);
    rtcReleaseGeometry(geometry);
    rtcCommitScene(h->scene);
    const auto stop = std::chrono::steady_clock::now();
    h->build_seconds = std::chrono::duration<double>(stop - start).count();
    h->build_peak_bytes = h->peak_bytes.load() - baseline;
    h->scene_bytes = h->current_bytes.load() - baseline;
    return rtcGetDeviceError(h->device) == RTC_ERROR_NONE && h->error.empty() ? kOk : kError;
}

long long begin_build(Handle* h) {
    if (h->scene) {
        rtcReleaseScene(h->scene);
        h->scene = nullptr;
    }
    const long long baseline = h->current_bytes.load();
    h->peak_bytes.store(baseline);
    return baseline;
}

}  // namespace

extern "C" {

// Creates a device with `threads` Embree threads (0 = Embree's default) plus an optional extra
// config string (e.g. "isa=avx2"). Returns nullptr and fills err on failure.
void* ed_create(int threads, const char* extra_config, char* err, int err_len) {
    auto* h = new Handle();
    h->threads = threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    std::string config = threads > 0 ? "threads=" + std::to_string(threads) : std::string();
    if (extra_config && *extra_config) config += (config.empty() ? "" : ",") + std::string(extra_config);
    h->device = rtcNewDevice(config.c_str());
    if (!h->device) {
        if (err && err_len > 0) {
            std::snprintf(err, static_cast<size_t>(err_len), "rtcNewDevice(\"%s\") failed: error %d",
                          config.c_str(), static_cast<int>(rtcGetDeviceError(nullptr)));
        }
        delete h;
        return nullptr;
    }
    rtcSetDeviceErrorFunction(h->device, error_function, h);
    rtcSetDeviceMemoryMonitorFunction(h->device, memory_monitor, h);
    return h;
}

void ed_release(void* handle) {
    auto* h = static_cast<Handle*>(handle);
    if (!h) return;
    if (h->scene) rtcReleaseScene(h->scene);
    if (h->device) rtcReleaseDevice(h->device);
    delete h;
}

long long ed_device_property(void* handle, int property) {
    auto* h = static_cast<Handle*>(handle);
    return static_cast<long long>(rtcGetDeviceProperty(h->device, static_cast<RTCDeviceProperty>(property)));
}

// Discs: xyzr (n, 4) float32 = centre and radius; normals (n, 3) float32. one_sided != 0 installs
// a filter that ignores hits from behind the disc (Embree's discs are two-sided otherwise).
int ed_build_discs(void* handle, const float* xyzr, const float* normals, long long n, int quality,
                   int scene_flags, int one_sided, char* err, int err_len) {
    auto* h = static_cast<Handle*>(handle);
    h->error.clear();
    const long long baseline = begin_build(h);
    h->vertices.assign(xyzr, xyzr + 4 * n);
    h->vertices.resize(4 * n + kBufferPadFloats, 0.0f);
    h->normals.assign(normals, normals + 3 * n);
    h->normals.resize(3 * n + kBufferPadFloats, 0.0f);
    h->indices.clear();
    h->input_bytes = n * static_cast<long long>(4 * sizeof(float) + 3 * sizeof(float));
    h->primitives = n;
    const auto start = std::chrono::steady_clock::now();
    RTCGeometry g = rtcNewGeometry(h->device, RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, h->vertices.data(), 0,
                               4 * sizeof(float), static_cast<size_t>(n));
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_NORMAL, 0, RTC_FORMAT_FLOAT3, h->normals.data(), 0,
                               3 * sizeof(float), static_cast<size_t>(n));
    if (one_sided) {
        rtcSetGeometryIntersectFilterFunction(g, one_sided_filter);
        rtcSetGeometryOccludedFilterFunction(g, one_sided_filter);
    }
    const int rc = commit_scene(h, g, quality, scene_flags, start, baseline);
    copy_error(h, err, err_len);
    return rc;
}

// Triangles: vertices (nv, 3) float32, faces (nf, 3) uint32.
int ed_build_triangles(void* handle, const float* vertices, long long nv, const uint32_t* faces,
                       long long nf, int quality, int scene_flags, char* err, int err_len) {
    auto* h = static_cast<Handle*>(handle);
    h->error.clear();
    const long long baseline = begin_build(h);
    h->vertices.assign(vertices, vertices + 3 * nv);
    h->vertices.resize(3 * nv + kBufferPadFloats, 0.0f);
    h->normals.clear();
    h->indices.assign(faces, faces + 3 * nf);
    h->input_bytes = nv * static_cast<long long>(3 * sizeof(float)) + nf * static_cast<long long>(3 * sizeof(uint32_t));
    h->primitives = nf;
    const auto start = std::chrono::steady_clock::now();
    RTCGeometry g = rtcNewGeometry(h->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, h->vertices.data(), 0,
                               3 * sizeof(float), static_cast<size_t>(nv));
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, h->indices.data(), 0,
                               3 * sizeof(uint32_t), static_cast<size_t>(nf));
    const int rc = commit_scene(h, g, quality, scene_flags, start, baseline);
    copy_error(h, err, err_len);
    return rc;
}

double ed_build_seconds(void* handle) { return static_cast<Handle*>(handle)->build_seconds; }
long long ed_build_peak_bytes(void* handle) { return static_cast<Handle*>(handle)->build_peak_bytes; }
long long ed_scene_bytes(void* handle) { return static_cast<Handle*>(handle)->scene_bytes; }
long long ed_input_bytes(void* handle) { return static_cast<Handle*>(handle)->input_bytes; }
long long ed_device_bytes(void* handle) { return static_cast<Handle*>(handle)->current_bytes.load(); }

// Closest hit. rays (n, 6) float32 origin + direction; t_out (n,) inf on miss; prim_out (n,)
// int32 -1 on miss (may be null); ng_out (n, 3) unit geometric normal, 0 on miss (may be null).
int ed_intersect(void* handle, const float* rays, long long n, float tnear, float tfar, int mode,
                 float* t_out, int32_t* prim_out, float* ng_out) {
    auto* h = static_cast<Handle*>(handle);
    if (!h->scene || !valid_mode(mode)) return kError;
    parallel_chunks(n, h->threads, [&](long long b, long long e) {
        switch (mode) {
            case 4: intersect_packets<4>(h, rays, b, e, tnear, tfar, t_out, prim_out, ng_out); break;
            case 8: intersect_packets<8>(h, rays, b, e, tnear, tfar, t_out, prim_out, ng_out); break;
            case 16: intersect_packets<16>(h, rays, b, e, tnear, tfar, t_out, prim_out, ng_out); break;
            default: intersect_single(h, rays, b, e, tnear, tfar, t_out, prim_out, ng_out); break;
        }
    });
    return kOk;
}

// Any hit in (tnear, tmax[i]). out (n,) uint8: 1 = occluded.
int ed_occluded(void* handle, const float* rays, long long n, float tnear, const float* tmax, int mode,
                uint8_t* out) {
    auto* h = static_cast<Handle*>(handle);
    if (!h->scene || !valid_mode(mode)) return kError;
    parallel_chunks(n, h->threads, [&](long long b, long long e) {
        switch (mode) {
            case 4: occluded_packets<4>(h, rays, b, e, tnear, tmax, out); break;
            case 8: occluded_packets<8>(h, rays, b, e, tnear, tmax, out); break;
            case 16: occluded_packets<16>(h, rays, b, e, tnear, tmax, out); break;
            default: occluded_single(h, rays, b, e, tnear, tmax, out); break;
        }
    });
    return kOk;
}

}  // extern "C"
