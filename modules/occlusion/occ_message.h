/* occ_message: one sweep's answer (occ_output_t) as the OCCLUSION message, for the
 * module's shell and its bench alike.
 *
 * The message points into r and into agents (filled by the call): both must outlive
 * its use; nothing is copied or freed. */
#ifndef OCC_MESSAGE_H
#define OCC_MESSAGE_H

#include <cstring>
#include <vector>

#include "core/occlusion.h"
#include "portobello_occlusion_t.h"

static inline portobello_occlusion_t occ_message(const occ_output_t &r, std::vector<portobello_agent_occlusion_t> *agents)
{
    agents->assign(r.agents.size(), portobello_agent_occlusion_t{});
    for (size_t i = 0; i < r.agents.size(); i++) {
        const occ_agent_out_t &g = r.agents[i];
        portobello_agent_occlusion_t &m = (*agents)[i];
        /* LCM's generated types take non-const pointers; encoding only reads them */
        m.agent_id = const_cast<char *>(g.id.c_str());
        m.visible_fraction = g.visible_fraction;
        m.nsamples = g.n;
        m.sample_x = const_cast<float *>(g.x); m.sample_y = const_cast<float *>(g.y); m.sample_z = const_cast<float *>(g.z);
        m.state = const_cast<int8_t *>(g.state);
        m.occluder_m = const_cast<float *>(g.occluder_m);
    }
    portobello_occlusion_t m = {};
    m.utime = r.utime;
    std::memcpy(m.viewer, r.viewer, sizeof m.viewer);
    m.eye_source = (int8_t)r.eye_source;
    m.nagents = (int32_t)agents->size();
    m.agents = agents->data();
    return m;
}

#endif
