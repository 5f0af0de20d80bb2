/* The director's agents as AGENTS message entries: one conversion for every program
 * that publishes them (the director's shell, simdrive's staged agents). No I/O. */
#ifndef DIR_AGENTS_MSG_H
#define DIR_AGENTS_MSG_H

#include "director.h"
#include "portobello_agent_t.h"

/* Fills msg[0..n-1] from out[0..n-1]. The strings of msg point into out (borrowed:
 * valid while out is), nothing is allocated. */
void dir_agents_to_msg(const dir_agent_out_t *out, int n, portobello_agent_t *msg);

#endif
