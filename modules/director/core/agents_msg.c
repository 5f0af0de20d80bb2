#include "agents_msg.h"

#include <string.h>

void dir_agents_to_msg(const dir_agent_out_t *out, int n, portobello_agent_t *msg)
{
    for (int i = 0; i < n; i++) {
        portobello_agent_t *g = &msg[i];
        const dir_agent_out_t *o = &out[i];
        g->id = (char *)o->id; g->kind = (char *)o->kind; g->model = (char *)o->model;
        memcpy(g->position, o->pos, sizeof g->position);
        g->yaw_rad = o->yaw;
        memcpy(g->velocity, o->vel, sizeof g->velocity);
        g->animation = (char *)o->animation;
        g->animation_phase = o->phase;
        g->in_render_range = o->in_range;
        g->distance_m = o->distance_m;
    }
}
