/*
 * What every model's model.c may ask of its variable table (plant_fmu/variables.py): whether
 * a value reference is in a group of variables.
 */
#ifndef VALUE_REFERENCES_H
#define VALUE_REFERENCES_H

/* Whether value reference vr is one of the count variables from first on. */
static inline int in_group(unsigned vr, unsigned first, unsigned count)
{
    return vr >= first && vr < first + count;
}

#endif
