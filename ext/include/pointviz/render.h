// pointviz — final frames: camera, materials, lights, shadows, reflections (issue "final frames").
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

#include "pointviz/geometry.h"
#include "pointviz/progress.h"

namespace pointviz {

/// Pinhole camera in the scene's local frame; the ray model of pointviz.Camera.
struct CameraModel {
    Vec3 eye, forward, right, up;   ///< orthonormal basis; up is the true up
    float tan_half = 0.36397f;      ///< tan(vertical fov / 2)
    int width = 640, height = 480;

    float aspect() const { return float(width) / float(height); }
    /// Angle subtended by one pixel at the image centre.
    float pixel_angle() const { return 2.f * std::atan(tan_half / float(height)); }
    /// Image-plane coordinates (at unit distance) of column `col` and row `row`.
    float plane_x(float col) const { return (2.f * col / float(width) - 1.f) * tan_half * aspect(); }
    float plane_y(float row) const { return (1.f - 2.f * row / float(height)) * tan_half; }
    /// Unit direction through the image-plane point (sx, sy).
    Vec3 direction_at(float sx, float sy) const { return normalize(forward + right * sx + up * sy); }
    /// Unit direction through (col + u, row + v), u, v in [0, 1).
    Vec3 direction(float col, float row) const { return direction_at(plane_x(col), plane_y(row)); }
};

/// Surface appearance. Colours are linear RGB.
struct Material {
    Vec3 base_color{0.8f, 0.8f, 0.8f};
    bool use_point_colors = true;   ///< multiply by the hit's colour (sRGB-decoded)
    float diffuse = 1.f;            ///< Lambert weight
    float specular = 0.15f;         ///< Blinn–Phong lobe weight
    float shininess = 48.f;         ///< Blinn–Phong exponent
    float mirror = 0.f;             ///< reflectivity in [0, 1]
    float roughness = 0.f;          ///< 0: sharp mirror; > 0: glossy reflections (lobe width)
    Vec3 checker{0.f, 0.f, 0.f};    ///< ground only: second colour of a checkerboard (0: none)
    float checker_size = 0.f;       ///< ground only: checker cell size (0: none)
};

enum class LightType : uint8_t { Directional = 0, Point = 1, Area = 2 };

/// A light. Directional: `direction` points toward the light, `angle` is its angular radius
/// (soft shadows). Point: `position`, inverse-square falloff, `radius` softens. Area: a
/// parallelogram at `position` spanned by `edge_u`, `edge_v`, emitting on both sides.
struct Light {
    LightType type = LightType::Directional;
    Vec3 color{1.f, 1.f, 1.f};      ///< linear RGB intensity
    Vec3 direction{0.f, 1.f, 0.f};
    float angle = 0.f;
    Vec3 position{0.f, 0.f, 0.f};
    float radius = 0.f;
    Vec3 edge_u{0.f, 0.f, 0.f}, edge_v{0.f, 0.f, 0.f};
    bool cast_shadows = true;       ///< false: no shadow rays (a fill light)
};

/// Sky seen by misses and the ambient term: a gradient from horizon to zenith.
struct Sky {
    Vec3 zenith{0.45f, 0.55f, 0.72f};
    Vec3 horizon{0.82f, 0.84f, 0.88f};
    Vec3 below{0.35f, 0.33f, 0.3f};
    Vec3 up{0.f, 1.f, 0.f};
    float ambient = 0.25f;          ///< strength of the sky's ambient light on surfaces
    bool background_is_sky = true;  ///< primary misses show the sky, else `background`
    Vec3 background{1.f, 1.f, 1.f};
    /// Sky visibility (ambient occlusion): the ambient term is scaled by the fraction of
    /// cosine-weighted rays of this length that leave the surface without meeting an object
    /// (the ground plane does not occlude: `below` already stands for it). 0: no occlusion.
    float occlusion_distance = 0.f;
    /// Primary hits of the ground farther than this from `ground_point` fade into the
    /// background colour, reaching it at twice the distance: a studio backdrop with no
    /// horizon line. 0: no fade.
    float ground_fade = 0.f;
};

/// Self-intersection policy for rays leaving a surface (shadow and reflection rays). Surfels
/// overlap and tilt: a neighbour of the hit disk may rise above the hit point's tangent plane by
/// up to about its radius on curved surfaces, and registered raw scans stack several noisy
/// layers a fraction of a radius apart. Rays therefore start `normal_offset` local radii above
/// the surface and ignore hits closer than `tmin` local radii. The local radius is the larger of
/// the blended disk radius and the pixel footprint (LoD disks are footprint-sized). Half these
/// values left visible shadow speckles on the Stanford dragon scans; contact shadows narrower
/// than two disk radii are what the policy gives up. benchmarks/diagnose_scans.py measures the
/// dragon's raw scans against its reconstruction under one hard light: isolated false-shadow
/// speckles on 8.8 / 4.5 / 1.1 / 0.6 % of lit pixels for offsets 0.25 / 0.5 / 1 / 2 radii
/// (0.17 % on clean surfels of the mesh at 1 radius: the rest comes from the stacked layers).
/// 2 / 4 radii was not taken: it moves shadows and reflections of LoD disks (footprint-sized)
/// visibly (the demo scene's LoD frame drops below 30 dB PSNR against full detail).
struct OffsetPolicy {
    float normal_offset = 1.0f;
    float tmin = 2.0f;
};

struct RenderSettings {
    int spp = 4;                 ///< samples per pixel (stratified)
    int reflections = 1;         ///< reflection bounces
    bool shadows = true;
    float lod_pixels = 1.f;      ///< 0: full detail
    /// Whether ray offsets grow with the pixel footprint (see OffsetPolicy): needed by the size
    /// rule, whose LoD disks reach a footprint and whose secondary rays stop at any node that
    /// small. The error budget turns it off unless the objects cover so little of the frame that
    /// the offsets' error fits in its share of the budget (pointviz.rendering.footprint_offsets):
    /// its secondary rays stop only at nodes flat enough for their kind's model and clear of
    /// their origin (lod.h), and the hit radius already covers a LoD disk, so the other frames
    /// keep full detail's offsets (the footprint-sized offsets cost the 8M striped torus 0.0024
    /// mean FLIP at 2.5x, 0.0004 at 7.5x).
    bool footprint_offsets = true;
    uint64_t seed = 0;
    /// Progressive rendering: this render traces samples `sample_offset .. sample_offset+spp-1`
    /// of a pixel's sample sequence, so that the mean of renders with offsets 0, spp, 2 spp, ...
    /// is the render with all those samples at once (same seed).
    uint32_t sample_offset = 0;
    /// Samples per pixel of the whole sequence this render is part of (0: `spp`). A sequence of
    /// one sample uses pixel centres; longer ones jitter every sample, the first one included.
    uint32_t sequence_spp = 0;
    int threads = 0;
    int tile = 16;               ///< tile edge in pixels
    int occlusion_rays = 2;      ///< sky-visibility rays per camera sample (1 on reflections)
    bool phase_times = false;    ///< fill RenderStats::ns (a clock read per phase and tile)
    /// A tile whose camera samples provably see only background (its corner rays' pyramid
    /// misses every object's bounds, and misses the ground or meets it beyond its fade) is
    /// written directly, without queueing a ray: per sample only the direction and the ground's
    /// distance, the same sums in the same order, so the frame is the same bits. false: every
    /// tile takes the general path (the oracle of the tests).
    bool background_shortcut = true;
    /// The ground's samples of a bounce shaded four at a time (shading_lanes.h): their fade,
    /// each directional light's direction and terms and their sky-visibility directions
    /// computed in SIMD lanes before the samples are shaded in order, with the scalar
    /// expressions in the same order, so the frame is the same bits. false: every sample
    /// shaded alone (the oracle of the tests).
    bool simd_lanes = true;
    OffsetPolicy offsets;
};

/// Output buffers, row-major from the top-left pixel.
struct FrameBuffers {
    std::vector<float> color;    ///< (h, w, 3) linear
    std::vector<float> depth;    ///< (h, w) mean distance over samples that hit; inf if none
    std::vector<float> normal;   ///< (h, w, 3) mean shading normal of the hits
    std::vector<float> alpha;    ///< (h, w) fraction of samples that hit geometry
    /// (h, w, 3) base colour seen by the samples, in [0, 1]: the first hit's diffuse albedo,
    /// followed through sharp mirror reflections (weighted as the colour is; a glossy surface
    /// counts with its own colour) and the background on misses: the denoiser's guide, where
    /// edges the tracer resolved stay sharp.
    std::vector<float> albedo;
    std::vector<float> object_alpha;   ///< (h, w) fraction of samples that hit an object (not the ground)
};

/// Where a render's time went, summed over the workers: nanoseconds of each worker's CPU time
/// when RenderSettings::phase_times asks for it (0 otherwise): each phase timed on the monotonic
/// clock, scaled per tile by the worker's CPU time over its elapsed time (one CPU-clock read,
/// a system call, per tile). `primary` and `reflection`: closest-hit queries of
/// the objects and the ground; `shadow`: shadow and sky-visibility rays against the objects and
/// the ground; `shading`: everything else a bounce does (materials, lights, sampling the
/// secondary rays); `tile`: a tile's setup (camera rays) and output.
struct PhaseTimes {
    std::atomic<uint64_t> primary{0}, reflection{0}, shadow{0}, shading{0}, tile{0};
};

/// Counters of one render.
struct RenderStats {
    std::atomic<uint64_t> primary{0}, shadow{0}, reflection{0};
    /// Rays of each kind that met an object's bounds, and so were traced against it (the rest
    /// cannot reach it and skip it).
    std::atomic<uint64_t> primary_traced{0}, shadow_traced{0}, reflection_traced{0};
    /// Camera samples of the tiles written as background without a ray
    /// (RenderSettings::background_shortcut).
    std::atomic<uint64_t> background{0};
    std::atomic<uint64_t> tiles_done{0};
    uint64_t tiles_total = 0;
    PhaseTimes ns;
};

/// What a frame shows: objects (geometry + material), an optional ground plane, lights, sky.
struct RenderScene {
    struct Object {
        std::shared_ptr<const Geometry> geometry;
        Material material;
    };
    std::vector<Object> objects;
    bool ground = false;
    Vec3 ground_point{0.f, 0.f, 0.f}, ground_normal{0.f, 1.f, 0.f};
    Material ground_material;
    std::vector<Light> lights;
    Sky sky;
    float scale = 1.f;   ///< size of the scene (bounding radius): floor of ray offsets
};

/// Renders a frame. Deterministic for a given seed whatever the thread count. `progress` counts
/// tiles (`total` is set first); its cancel flag stops the render between tiles (the buffers are
/// then incomplete: callers must discard them). Returns false when cancelled.
bool render(const RenderScene &scene, const CameraModel &camera, const RenderSettings &settings,
            FrameBuffers &out, RenderStats &stats, Progress &progress);

}  // namespace pointviz
