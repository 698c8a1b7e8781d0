// pointviz — collapsing the binary QSplat tree into the wide tree.
#include <cstring>
#include <limits>

#include "pointviz/wide_node.h"

namespace pointviz {

void collapse_tree(const std::vector<Node> &nodes, const std::vector<Box> &boxes,
                   uint32_t box_depth, std::vector<WideNode> &wide,
                   std::vector<WideBoxes> &wide_boxes) {
    wide.clear();
    wide_boxes.clear();
    if (nodes.empty() || nodes[0].is_leaf()) return;
    // Breadth-first: the binary node and depth each wide node stands for, in creation order.
    struct Pending {
        uint32_t bin;
        uint32_t depth;
    };
    std::vector<Pending> queue{{0u, 0u}};
    for (size_t q = 0; q < queue.size(); ++q) {
        const Pending x = queue[q];
        WideNode w;
        std::memset(static_cast<void *>(&w), 0, sizeof(w));
        WideBoxes wb;
        std::memset(static_cast<void *>(&wb), 0, sizeof(wb));
        bool any_box = false;
        const uint32_t mid = nodes[x.bin].index();
        int lane = 0;
        auto add_lane = [&](uint32_t y, uint8_t parent, uint32_t depth) {
            const Node &nd = nodes[y];
            w.cx[lane] = nd.c.x, w.cy[lane] = nd.c.y, w.cz[lane] = nd.c.z;
            w.r[lane] = nd.radius;
            const Vec3 a = nd.axis();
            w.ax[lane] = a.x, w.ay[lane] = a.y, w.az[lane] = a.z;
            w.slab[lane] = nd.slab_q() < kNoSlab ? nd.slab_half_width()
                                                 : std::numeric_limits<float>::infinity();
            w.cone[lane] = nd.has_cone() ? nd.cone() : std::numeric_limits<float>::infinity();
            w.parent[lane] = parent;
            w.depth[lane] = uint8_t(depth);
            if (nd.is_leaf()) {
                w.child[lane] = nd.index();
                w.lane_count[lane] = uint8_t(nd.count());
            } else {
                w.child[lane] = uint32_t(queue.size());
                w.lane_count[lane] = kInteriorLane;
                queue.push_back({y, depth});
            }
            if (depth < box_depth && y < boxes.size()) {
                const Box &b = boxes[y];
                wb.lox[lane] = b.lo.x, wb.loy[lane] = b.lo.y, wb.loz[lane] = b.lo.z;
                wb.hix[lane] = b.hi.x, wb.hiy[lane] = b.hi.y, wb.hiz[lane] = b.hi.z;
                any_box = true;
            }
            w.valid |= uint8_t(1u << lane);
            ++lane;
        };
        for (uint8_t m = 0; m < 2; ++m) {
            const uint32_t a = mid + m;
            const Node &an = nodes[a];
            MidNode &mn = w.mids[m];
            mn.c = an.c;
            mn.r = an.radius;
            mn.axis = an.axis();
            mn.cone = an.has_cone() ? an.cone() : std::numeric_limits<float>::infinity();
            mn.child = an.is_leaf() ? kNoChild : an.index();
            mn.index = a;
            if (an.is_leaf()) {
                add_lane(a, kLaneIsMid, x.depth + 1);
            } else {
                const uint32_t g = nodes[a].index();
                add_lane(g, m, x.depth + 2);
                add_lane(g + 1, m, x.depth + 2);
            }
        }
        for (; lane < kWide; ++lane) w.child[lane] = kNoChild;
        wide.push_back(w);
        // Depth never decreases along the queue, so the wide nodes with boxes are a prefix.
        if (any_box) {
            wide_boxes.resize(wide.size());
            wide_boxes.back() = wb;
        }
    }
}

}  // namespace pointviz
