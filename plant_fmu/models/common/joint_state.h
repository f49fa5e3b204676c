/*
 * What the arms' model.c share about their variable table (plant_fmu/variables.py): the
 * joint positions q and velocities qdot are adjacent (the first states), each started from
 * its parameter q0, qdot0.
 */
#ifndef JOINT_STATE_H
#define JOINT_STATE_H

#include <string.h>

#include "value_references.h"

/* q and qdot from their start values q0 and qdot0. */
static inline void start_joints(ModelState *s)
{
    memcpy(&s->v[VR_q], &s->v[VR_q0], N_LINKS * sizeof(double));
    memcpy(&s->v[VR_qdot], &s->v[VR_qdot0], N_LINKS * sizeof(double));
}

#endif
