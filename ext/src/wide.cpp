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

}  // namespace

WideTree::WideTree(const std::vector<Node> &nodes, const std::vector<uint32_t> &level_start,
                   uint32_t box_depth)
    : box_depth_(box_depth) {
    const size_t levels = level_start.empty() ? 0 : level_start.size() - 1;
    size_t count = 0;
    for (size_t lvl = first_level(box_depth); lvl < levels; lvl += 2)
        for (uint32_t i = level_start[lvl]; i < level_start[lvl + 1]; ++i) count += !nodes[i].is_leaf();
    if (count == 0) return;
    nodes_.resize(count);
    of_.assign(nodes.size(), kNoWide);
    size_t next = 0;
    for (size_t lvl = first_level(box_depth); lvl < levels; lvl += 2)
        for (uint32_t i = level_start[lvl]; i < level_start[lvl + 1]; ++i)
            if (!nodes[i].is_leaf()) of_[i] = uint32_t(next++);
    for (size_t lvl = first_level(box_depth); lvl < levels; lvl += 2) {
        for (uint32_t i = level_start[lvl]; i < level_start[lvl + 1]; ++i) {
            const Node &p = nodes[i];
            if (p.is_leaf()) continue;
            WideNode &w = nodes_[of_[i]];
            w = WideNode{};
            for (int k = 0; k < kWideUsed; ++k) clear_lane(w, k);
            for (uint32_t j = 0; j < 2; ++j) {
                const Node &x = nodes[p.index() + j];
                put_lane(w, int(j), x);
                if (x.is_leaf()) continue;
                for (uint32_t g = 0; g < 2; ++g) {
                    const uint32_t y = x.index() + g;
                    const int lane = int(2 + 2 * j + g);
                    put_lane(w, lane, nodes[y]);
                    if (!nodes[y].is_leaf()) w.ref[lane] = of_[y];
                }
            }
        }
    }
}

}  // namespace pointviz
