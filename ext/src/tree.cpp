// pointviz — building the surfel hierarchy.
#include "pointviz/tree.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include "pointviz/parallel.h"

namespace pointviz {
namespace {

/// Per-node sums carried up the tree during the build.
struct Sums {
    Vec3 nsum;     ///< sum of normals
    Vec3 lsum;     ///< sum of linear colours (sRGB-decoded): the node's mean colour
};

/// The linear value of each 8-bit sRGB code (the renderer decodes hit colours the same way).
struct SrgbTable {
    float linear[256];
    SrgbTable() {
        for (int i = 0; i < 256; ++i) {
            const float c = float(i) * (1.f / 255.f);
            linear[i] = c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
        }
    }
    Vec3 decode(uint32_t rgba) const {
        return {linear[rgba & 0xffu], linear[(rgba >> 8) & 0xffu], linear[(rgba >> 16) & 0xffu]};
    }
};
inline float srgb_encode(float v) {
    return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.f / 2.4f) - 0.055f;
}

/// Component-wise min / max that ignore a NaN in `b` (as vmin / vmax do) but compile to one
/// instruction each instead of calls to fminf / fmaxf: the build's box loops run over every
/// surfel at every level (a third of the topology's time went to those calls).
inline Vec3 lower(Vec3 a, Vec3 b) {
    return {b.x < a.x ? b.x : a.x, b.y < a.y ? b.y : a.y, b.z < a.z ? b.z : a.z};
}
inline Vec3 upper(Vec3 a, Vec3 b) {
    return {b.x > a.x ? b.x : a.x, b.y > a.y ? b.y : a.y, b.z > a.z ? b.z : a.z};
}

/// Seconds since `t0`.
double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

SurfelTree::SurfelTree(const SurfelArrays &in, const double origin[3], const BuildOptions &opt) {
    SurfelTreeBuild build(in.points, in.n, origin, opt);
    build.add_surfels(in.normals, in.radii, in.colors);
    *this = build.finish();
}

void SurfelTreeBuild::check_stage(int stage) const {
    if (stage_ != stage)
        throw std::logic_error(stage_ == 4 ? "the tree build is spent: finish() ran already"
                                           : "tree build stages out of order: add_surfels(), then finish()");
}

SurfelTreeBuild::SurfelTreeBuild(const double *points, size_t n, const double origin[3],
                                 const BuildOptions &opt) {
    auto t0 = std::chrono::steady_clock::now();
    if (n == 0) throw std::invalid_argument("cannot build a tree of zero surfels");
    if (n >= kMaxTreeSurfels)
        throw std::length_error("too many surfels for one tree (limit 2^27 = 134,217,728)");
    n_ = n;
    leaf_ = std::clamp<uint32_t>(opt.leaf_size, 1u, kMaxLeafSize);
    box_depth_ = opt.box_depth;
    wide_ = opt.wide;
    threads_ = resolve_threads(opt.threads);
    const uint32_t leaf = leaf_;
    const int threads = threads_;
    for (int k = 0; k < 3; ++k) tree_.origin_[k] = origin[k];

    std::vector<Item> &items = items_;
    items.resize(n);
    parallel_for(n, 1 << 16, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            const double *p = points + 3 * i;
            items[i] = {{float(p[0] - origin[0]), float(p[1] - origin[1]), float(p[2] - origin[2])},
                        uint32_t(i)};
        }
    });

    // Topology, one level at a time: split at the (leaf-aligned) median of the longest axis of
    // the centres' box. The median (not the spatial midpoint) bounds the depth by
    // log2(n / leaf) + 1 whatever the distribution (duplicates, outliers), so traversal can use
    // a fixed-size stack.
    std::vector<Range> &ranges = ranges_;
    std::vector<uint32_t> &first_child = first_child_;
    std::vector<uint32_t> &level_start_ = tree_.level_start_;
    ranges = {{0u, uint32_t(n)}};
    first_child = {0u};
    level_start_ = {0u};
    size_t lb = 0, le = 1;
    for (;;) {
        std::vector<uint32_t> child_of(le - lb, 0u);
        size_t next = le;
        for (size_t i = lb; i < le; ++i)
            if (ranges[i].size() > leaf) {
                child_of[i - lb] = uint32_t(next);
                next += 2;
            }
        if (next == le) break;
        ranges.resize(next);
        first_child.resize(next, 0u);
        for (size_t i = lb; i < le; ++i) first_child[i] = child_of[i - lb];
        parallel_for(le - lb, 1, threads, [&](size_t b, size_t e, int) {
            for (size_t j = b; j < e; ++j) {
                size_t i = lb + j;
                Range r = ranges[i];
                if (r.size() <= leaf) continue;
                Vec3 lo{kInf, kInf, kInf}, hi{-kInf, -kInf, -kInf};
                for (uint32_t k = r.b; k < r.e; ++k) {
                    lo = lower(lo, items[k].p);
                    hi = upper(hi, items[k].p);
                }
                Vec3 ext = hi - lo;
                int axis = ext.x >= ext.y ? (ext.x >= ext.z ? 0 : 2) : (ext.y >= ext.z ? 1 : 2);
                // Near-median: the left side gets half of the leaves' worth of surfels, so
                // every leaf but one is full and the tree has ceil(n / leaf) leaves.
                uint32_t leaves = (r.size() + leaf - 1) / leaf;
                uint32_t mid = r.b + std::min(r.size() - 1, ((leaves + 1) / 2) * leaf);
                std::nth_element(items.begin() + r.b, items.begin() + mid, items.begin() + r.e,
                                 [axis](const Item &a, const Item &c) { return a.p[axis] < c.p[axis]; });
                uint32_t fc = first_child[i];
                ranges[fc] = {r.b, mid};
                ranges[fc + 1] = {mid, r.e};
            }
        });
        level_start_.push_back(uint32_t(le));
        lb = le;
        le = next;
    }
    level_start_.push_back(uint32_t(le));
    tree_.build_seconds_ = seconds_since(t0);
}

void SurfelTreeBuild::add_surfels(const float *normals, const float *radii, const float *colors) {
    check_stage(2);
    auto t0 = std::chrono::steady_clock::now();
    const size_t n = n_;
    const int threads = threads_;
    std::vector<Surfel> &surfels_ = tree_.surfels_;
    std::vector<uint32_t> &order_ = tree_.order_;
    const std::vector<Item> &items = items_;

    // Surfels in leaf order.
    surfels_.resize(n);
    order_.resize(n);
    parallel_for(n, 1 << 16, threads, [&](size_t b, size_t e, int) {
        for (size_t k = b; k < e; ++k) {
            uint32_t i = items[k].i;
            order_[k] = i;
            const float *nn = normals + 3 * i;
            Surfel &s = surfels_[k];
            s.p = items[k].p;
            s.r = radii[i];
            s.n = normalize(Vec3{nn[0], nn[1], nn[2]});
            s.rgba = colors ? pack_rgb(colors[3 * i], colors[3 * i + 1], colors[3 * i + 2])
                               : 0xffffffffu;
        }
    });
    std::vector<Item>().swap(items_);
    stage_ = 3;
    tree_.build_seconds_ += seconds_since(t0);
}

SurfelTree SurfelTreeBuild::finish() {
    check_stage(3);
    auto t0 = std::chrono::steady_clock::now();
    const uint32_t leaf = leaf_;
    const int threads = threads_;
    const std::vector<Range> &ranges = ranges_;
    const std::vector<uint32_t> &first_child = first_child_;
    const std::vector<uint32_t> &level_start_ = tree_.level_start_;
    const std::vector<Surfel> &surfels_ = tree_.surfels_;
    std::vector<Node> &nodes_ = tree_.nodes_;
    const size_t n_nodes = level_start_.back();

    // Attributes, bottom-up.
    nodes_.resize(n_nodes);
    std::vector<Box> boxes(n_nodes);
    std::vector<Sums> sums(n_nodes);
    const SrgbTable srgb;
    const uint32_t levels = uint32_t(level_start_.size() - 1);
    for (uint32_t lvl = levels; lvl-- > 0;) {
        size_t b0 = level_start_[lvl], e0 = level_start_[lvl + 1];
        parallel_for(e0 - b0, 64, threads, [&](size_t b, size_t e, int) {
            for (size_t j = b; j < e; ++j) {
                size_t i = b0 + j;
                Range r = ranges[i];
                Node &nd = nodes_[i];
                Sums &sm = sums[i];
                const bool interior = r.size() > leaf;
                Vec3 c{0, 0, 0};
                if (!interior) {
                    Box bx{{kInf, kInf, kInf}, {-kInf, -kInf, -kInf}};
                    sm.nsum = sm.lsum = {0, 0, 0};
                    for (uint32_t k = r.b; k < r.e; ++k) {
                        const Surfel &s = surfels_[k];
                        c += s.p;
                        sm.nsum += s.n;
                        sm.lsum += srgb.decode(s.rgba);
                        Vec3 ext{s.r, s.r, s.r};
                        bx.lo = lower(bx.lo, s.p - ext);
                        bx.hi = upper(bx.hi, s.p + ext);
                    }
                    c = c / float(r.size());
                    boxes[i] = bx;
                    nd.index_count = r.b | (r.size() << 27);
                } else {
                    uint32_t fc = first_child[i];
                    float w0 = float(ranges[fc].size()), w1 = float(ranges[fc + 1].size());
                    c = (nodes_[fc].c * w0 + nodes_[fc + 1].c * w1) / (w0 + w1);
                    sm.nsum = sums[fc].nsum + sums[fc + 1].nsum;
                    sm.lsum = sums[fc].lsum + sums[fc + 1].lsum;
                    boxes[i] = {vmin(boxes[fc].lo, boxes[fc + 1].lo), vmax(boxes[fc].hi, boxes[fc + 1].hi)};
                    nd.index_count = fc;
                }
                nd.c = c;
                float nlen = length(sm.nsum);
                Vec3 axis = nlen > 0.f ? sm.nsum / nlen : Vec3{0, 0, 1};
                // A mean normal this short means opposite normals cancel: no useful cone.
                bool degenerate = nlen < 1e-3f * float(r.size());
                // Exact sphere, cone and slab from the subtree's own surfels, in one pass:
                // O(n) per level. Cone and slab are measured against the stored (quantised)
                // axis, the one traversal uses. A disk (p, n, r) reaches
                // |dot(p - c, a)| + r * sqrt(|a|^2 - dot(n, a)^2) off the plane along a.
                for (int k = 0; k < 3; ++k) nd.axis_q[k] = quantize_axis(axis[k]);
                const Vec3 aq = nd.axis();
                const float aq2 = length2(aq);
                // The node's colour is its surfels' mean radiance: the mean of their linear
                // colours, coded back to sRGB (a mean of the codes is darker wherever the
                // colours differ, and a stopped node would darken the object: benchmarks/
                // README.md, "Issue 18, the colour term against what FLIP sees"). The colour
                // spread is the RMS deviation of the codes from that colour (at least their
                // deviation from their own mean: still a bound of it).
                const Vec3 ml = sm.lsum / float(r.size());
                const uint32_t node_rgb = pack_rgb(srgb_encode(ml.x), srgb_encode(ml.y), srgb_encode(ml.z));
                const Vec3 mc{channel(node_rgb, 0), channel(node_rgb, 1), channel(node_rgb, 2)};
                float radius = 0.f, cosmin = 1.f, h = 0.f, cdev = 0.f;
                for (uint32_t k = r.b; k < r.e; ++k) {
                    const Surfel &s = surfels_[k];
                    Vec3 pc = s.p - c;
                    cdev += length2(Vec3{channel(s.rgba, 0), channel(s.rgba, 1), channel(s.rgba, 2)} - mc);
                    float na = dot(s.n, aq);
                    radius = std::max(radius, length(pc) + s.r);
                    cosmin = std::min(cosmin, na);
                    h = std::max(h, std::fabs(dot(pc, aq)) + s.r * std::sqrt(std::max(0.f, aq2 - na * na)));
                }
                float theta = degenerate ? 3.1415927f
                                         : std::acos(std::clamp(cosmin / std::sqrt(aq2), -1.f, 1.f));
                // Rounding: radius from float math; grow by a relative ulp-scale margin.
                // The colour spread rides in the radius's low bits (rounded up: still a bound).
                nd.radius = radius_with_byte(radius * (1.f + 1e-6f) + 1e-7f,
                                             quantize_colour_spread(std::sqrt(cdev / float(r.size()))));
                if (theta >= 1.5707963f) {
                    nd.cone_q = kConeNeverQ;
                } else {
                    float q = std::ceil((std::sin(theta) + kConeSlack) * kConeScale);
                    // (written so that a NaN from an infinite radius lands on the safe side)
                    nd.cone_q = q < float(kConeNeverQ - 1) ? uint16_t(q) : uint16_t(kConeNeverQ - 1);
                }
                uint32_t slab_q = kNoSlab;
                if (!degenerate && radius > 0.f) {
                    // Rounding margin: float error of the dot products, relative to the radius.
                    float q = std::ceil((h * (1.f + 1e-5f) + 1e-6f * radius) / radius * 255.f);
                    slab_q = q < float(kNoSlab) ? uint32_t(q) : kNoSlab;  // NaN: no slab
                }
                nd.rgb_slab = (node_rgb & 0xffffffu) | (slab_q << 24);
            }
        });
    }

    std::vector<Sums>().swap(sums);
    std::vector<Range>().swap(ranges_);
    std::vector<uint32_t>().swap(first_child_);
    tree_.box_depth_ = std::min<uint32_t>(box_depth_, levels);
    boxes.resize(level_start_[tree_.box_depth_]);
    boxes.shrink_to_fit();
    if (wide_) tree_.wide_ = WideTree(nodes_, boxes, level_start_, tree_.box_depth_);
    tree_.boxes_ = std::move(boxes);
    tree_.build_seconds_ += seconds_since(t0);
    stage_ = 4;
    return std::move(tree_);
}

size_t SurfelTree::memory_bytes() const {
    return surfels_.size() * sizeof(Surfel) + nodes_.size() * sizeof(Node) +
           boxes_.size() * sizeof(Box) + wide_.memory_bytes() + order_.size() * sizeof(uint32_t) +
           level_start_.size() * sizeof(uint32_t);
}

}  // namespace pointviz
