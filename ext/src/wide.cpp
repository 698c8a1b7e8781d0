// pointviz — collapsing the binary hierarchy into wide nodes (wide.h).
#include "pointviz/wide.h"

#include <limits>

namespace pointviz {

namespace {

/// Writes binary node `nd` into lane `k` of `w`.
void put_lane(WideNode &w, int k, const Node &nd) {
    w.cx[k] = nd.c.x;
    w.cy[k] = nd.c.y;
    w.cz[k] = nd.c.z;
    w.r[k] = nd.radius;
    w.ax[k] = nd.axis_q[0];
    w.ay[k] = nd.axis_q[1];
    w.az[k] = nd.axis_q[2];
    w.cone_q[k] = nd.cone_q;
    w.slab_q[k] = uint8_t(nd.slab_q());
    w.ref[k] = nd.is_leaf() ? nd.index_count : 0u;
}

/// An absent lane: never hit (NaN radius), no cone, no slab.
void clear_lane(WideNode &w, int k) {
    w.cx[k] = w.cy[k] = w.cz[k] = 0.f;
    w.r[k] = std::numeric_limits<float>::quiet_NaN();
    w.ax[k] = w.ay[k] = w.az[k] = 0;
    w.cone_q[k] = kConeNeverQ;
    w.slab_q[k] = uint8_t(kNoSlab);
    w.ref[k] = 0u;
}


/// Writes binary node `nd` with box `b` into lane `k` of `w`.
void put_box_lane(WideBoxNode &w, int k, const Node &nd, const Box &b) {
    w.lx[k] = b.lo.x;
    w.ly[k] = b.lo.y;
    w.lz[k] = b.lo.z;
    w.hx[k] = b.hi.x;
    w.hy[k] = b.hi.y;
    w.hz[k] = b.hi.z;
    w.ax[k] = nd.axis_q[0];
    w.ay[k] = nd.axis_q[1];
    w.az[k] = nd.axis_q[2];
    w.cone_q[k] = nd.cone_q;
    w.ref[k] = nd.is_leaf() ? nd.index_count : 0u;
}

/// Fills the six lanes of P = `nodes[i]` with `put(lane, binary index)`, and the refs of its
/// interior grandchildren with their wide nodes.
template <class W, class Put>
void fill(W &w, const std::vector<Node> &nodes, uint32_t i, const std::vector<uint32_t> &of,
          Put put) {
    const Node &p = nodes[i];
    for (uint32_t j = 0; j < 2; ++j) {
        const uint32_t x = p.index() + j;
        put(int(j), x);
        if (nodes[x].is_leaf()) continue;
        for (uint32_t g = 0; g < 2; ++g) {
            const uint32_t y = nodes[x].index() + g;
            const int lane = int(2 + 2 * j + g);
            put(lane, y);
            if (!nodes[y].is_leaf()) w.ref[lane] = of[y];
        }
    }
}

}  // namespace

WideTree::WideTree(const std::vector<Node> &nodes, const std::vector<Box> &boxes,
                   const std::vector<uint32_t> &level_start, uint32_t box_depth)
    : box_depth_(box_depth) {
    const uint32_t levels = level_start.empty() ? 0 : uint32_t(level_start.size() - 1);
    const uint32_t first = first_level(box_depth);
    // Index every interior node of a wide level (same parity as first) in its kind's vector.
    size_t n_box = 0, n_sphere = 0;
    of_.assign(nodes.size(), kNoWide);
    for (uint32_t lvl = first % 2; lvl < levels; lvl += 2)
        for (uint32_t i = level_start[lvl]; i < level_start[lvl + 1]; ++i)
            if (!nodes[i].is_leaf()) of_[i] = uint32_t(box_level(lvl) ? n_box++ : n_sphere++);
    if (n_box + n_sphere == 0) {
        of_.clear();
        return;
    }
    nodes_.resize(n_sphere);
    box_nodes_.resize(n_box);
    for (uint32_t lvl = first % 2; lvl < levels; lvl += 2) {
        for (uint32_t i = level_start[lvl]; i < level_start[lvl + 1]; ++i) {
            if (nodes[i].is_leaf()) continue;
            if (box_level(lvl)) {
                WideBoxNode &w = box_nodes_[of_[i]];
                w = WideBoxNode{};
                fill(w, nodes, i, of_, [&](int k, uint32_t x) { put_box_lane(w, k, nodes[x], boxes[x]); });
            } else {
                WideNode &w = nodes_[of_[i]];
                w = WideNode{};
                for (int k = 0; k < kWideUsed; ++k) clear_lane(w, k);
                fill(w, nodes, i, of_, [&](int k, uint32_t x) { put_lane(w, k, nodes[x]); });
            }
        }
    }
}

}  // namespace pointviz
