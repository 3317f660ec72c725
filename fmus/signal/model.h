/*
 * Model-private data of a signal-playback FMU (see README.md in this folder): none. The
 * sampled signals are the generated table signal_table.h.
 */
#ifndef SIGNAL_MODEL_H
#define SIGNAL_MODEL_H

/* Co-simulation only: the outputs jump at the samples, which model exchange would need time
 * events for; the boilerplate refuses model-exchange instances. */
#define MODEL_CO_SIMULATION_ONLY 1

typedef struct {
    int unused; /* C has no empty structs */
} ModelData;

#endif
