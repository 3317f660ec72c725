/*
 * Stabilisation holds of the flight-test campaign, compiled with the helicopter model.
 *
 * The law is sysid.flight_test.campaign's secondary-axis holds (attitude holds on the cyclic,
 * heading hold on pedal, vertical-speed hold on collective, outer u/v loops on the attitude
 * references), evaluated in the campaign's analysis units (ft/s, deg/s, deg) with the same
 * floating-point operations in the same order as the Python reference, so that a campaign
 * flown with the holds in the FMU has the same bytes as one flown with the holds in Python.
 * Gains, trim references and dead bands are FMU parameters (hold_* in variables.csv) set
 * from Python per manoeuvre; the inputs lon lat col ped are the pilot command (trim,
 * excitation and off-axis activity) and the outputs lon_applied ... ped_applied the controls
 * the actuators receive: the pilot command plus the holds, saturated to 0-100 %.
 *
 * With hold_enabled = 0 (the default) the model is unchanged: the actuators follow the inputs.
 * With hold_enabled = 1:
 *   co-simulation   each fmi2DoStep samples the law once at its start (the state and inputs
 *                   of the communication point) and holds the result over the step, as a
 *                   100 Hz flight-control computer does; lon_applied ... report it.
 *   model exchange  the law acts continuously on the current state (no sampling).
 *
 * Only the data type is needed by model.h (it is part of ModelData, hence of FMU-state
 * snapshots); the functions take the real-variable vector r (indexed by value reference) so
 * that this file does not depend on the FMI-version glue.
 */
#ifndef HELICOPTER_HOLDS_H
#define HELICOPTER_HOLDS_H

#include <stddef.h>

/* Index of each control in the arrays below: the order of sysid.core.units.CONTROLS. */
enum { HOLD_LON = 0, HOLD_LAT = 1, HOLD_COL = 2, HOLD_PED = 3, HOLD_CONTROLS = 4 };

typedef struct {
    double applied[HOLD_CONTROLS]; /* controls held over the current co-simulation step, % */
    double hdot0;                  /* climb rate at the trim references, ft/s */
    int held;                      /* 1 once a co-simulation step has sampled the law */
} HoldsData;

/* Validate the hold parameters and derive constants; 0 on success, otherwise -1 with a
 * message naming the parameter written to message[size]. */
int holds_initialize(const double *r, HoldsData *h, char *message, size_t size);

/* The controls (%) the actuators follow for the states x: the inputs (holds off), the held
 * sample (inside a co-simulation step) or the law at x (model exchange). */
void holds_controls(const double *r, const HoldsData *h, const double *x,
                    double u[HOLD_CONTROLS]);

/* Start of a co-simulation step: sample the law at the current states and inputs. */
void holds_sample(const double *r, HoldsData *h);

/* Write the outputs lon_applied ... ped_applied into r. */
void holds_outputs(double *r, const HoldsData *h);

#endif
