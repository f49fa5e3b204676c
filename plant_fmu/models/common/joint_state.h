/*
 * What the models' model.c share about their variable table (plant_fmu/variables.py): the
 * joint positions q and velocities qdot are adjacent (the first states), each started from
 * its parameter q0, qdot0; and a value reference's place in a group of variables.
 */
#ifndef JOINT_STATE_H
#define JOINT_STATE_H

#include <string.h>

/* q and qdot from their start values q0 and qdot0. */
static inline void start_joints(ModelState *s)
{
    memcpy(&s->v[VR_q], &s->v[VR_q0], N_LINKS * sizeof(double));
    memcpy(&s->v[VR_qdot], &s->v[VR_qdot0], N_LINKS * sizeof(double));
}

/* Whether value reference vr is one of the count variables from first on. */
static inline int in_group(unsigned vr, unsigned first, unsigned count)
{
    return vr >= first && vr < first + count;
}

#endif
