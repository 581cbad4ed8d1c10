/*
 * The hand of the device stand-ins (hd_standin.c, dhd_standin.c): one model of a hand holding
 * a haptic device, shared by both so that a press through either stand-in is the same press.
 *
 * A point mass (the device's moving mass at the tip and the part of the hand moving with it)
 * held by a grip spring-damper toward a scripted target, with a little friction of the device's
 * own: the model of the project's simulated device (device/src/sim.rs, SimParams::default). The
 * target presses along −y from PRESS_APPROACH_MM above a press point to a depth below it and
 * back (the "press": x, y, z of the point (mm), depth (mm), period (s)), read from an
 * environment variable so that a test running the server as a program can place it.
 *
 * Header-only (static functions): each stand-in is one shared library with its state private,
 * and this file holds no state.
 */

#ifndef STANDIN_HAND_H
#define STANDIN_HAND_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HAND_MASS_KG 0.145
#define HAND_STIFFNESS_N_PER_M 300.0
#define HAND_DAMPING_N_S_PER_M 2.0
#define DEVICE_DAMPING_N_S_PER_M 0.05
#define HAND_SUBSTEPS 10
/* The longest substep: a long step is integrated in as many more substeps as it is longer, so
 * the hand moves through it as it would in real time, however stiff and light the grip. */
#define HAND_MAX_SUBSTEP_S 1e-4
/* The target starts this far above the press point. */
#define PRESS_APPROACH_MM 20.0
#define PI 3.14159265358979323846

/* The grip and the moving mass. */
typedef struct {
    double stiffness_n_per_m;
    double damping_n_s_per_m;
    double mass_kg;
} Grip;

static const Grip DEFAULT_GRIP = {HAND_STIFFNESS_N_PER_M, HAND_DAMPING_N_S_PER_M, HAND_MASS_KG};

/* The target and its velocity (mm, mm/s) at script time `t` (s): a press along −y from
 * PRESS_APPROACH_MM above the point to `depth` below it and back, with a cosine profile, so
 * neither the target nor its velocity ever jumps (also at the wrap of the period). */
static void press_target(const double press[5], double t, double target_mm[3],
                         double target_mm_s[3]) {
    double travel = PRESS_APPROACH_MM + press[3];
    double period = press[4];
    double offset = 0.0;
    double rate = 0.0;
    if (period > 0.0) {
        double phase = fmod(t, period) / period;
        offset = travel * (0.5 - 0.5 * cos(2.0 * PI * phase));
        rate = travel * PI / period * sin(2.0 * PI * phase);
    }
    target_mm[0] = press[0];
    target_mm[1] = press[1] + PRESS_APPROACH_MM - offset;
    target_mm[2] = press[2];
    target_mm_s[0] = 0.0;
    target_mm_s[1] = -rate;
    target_mm_s[2] = 0.0;
}

/* Reads the press from the environment variable `name` ("x_mm,y_mm,z_mm,depth_mm,period_s"); a
 * malformed value is said once on stderr (prefixed `who`) and the default used, rather than
 * quietly pressing somewhere else. */
static void read_press(const char *name, const char *who, double press[5]) {
    const double defaults[5] = {0.0, 0.0, 0.0, 8.0, 3.0};
    memcpy(press, defaults, sizeof(defaults));
    const char *text = getenv(name);
    if (text == NULL || text[0] == '\0') return;
    double v[5];
    char tail;
    int n = sscanf(text, " %lf , %lf , %lf , %lf , %lf %c", &v[0], &v[1], &v[2], &v[3], &v[4],
                   &tail);
    int ok = n == 5;
    for (int i = 0; ok && i < 5; i++) ok = isfinite(v[i]);
    ok = ok && v[3] >= 0.0 && v[4] > 0.0;
    if (!ok) {
        fprintf(stderr,
                "%s: %s=\"%s\" is not \"x_mm,y_mm,z_mm,depth_mm,period_s\" with depth >= 0 and "
                "period > 0; using the default 0,0,0,8,3\n",
                who, name, text);
        return;
    }
    memcpy(press, v, sizeof(v));
}

/* Moves the hand by `step_s` from script time `time_s` under `force_n` (N, held across the
 * step: a zero-order hold, as sim.rs), semi-implicit Euler in HAND_SUBSTEPS substeps (more for
 * a long step, none longer than HAND_MAX_SUBSTEP_S). SI units, device frame. */
static void hand_step(const Grip *grip, const double press[5], double time_s, double step_s,
                      const double force_n[3], double position_m[3], double velocity_m_s[3]) {
    int substeps = HAND_SUBSTEPS;
    double needed = ceil(step_s / HAND_MAX_SUBSTEP_S - 1e-9);
    if (needed > substeps) substeps = needed < 1e6 ? (int)needed : 1000000;
    double h = step_s / substeps;
    for (int step = 0; step < substeps; step++) {
        double target_mm[3], target_mm_s[3];
        press_target(press, time_s + step * h, target_mm, target_mm_s);
        for (int i = 0; i < 3; i++) {
            double pull = grip->stiffness_n_per_m * (target_mm[i] * 1e-3 - position_m[i]) +
                          grip->damping_n_s_per_m * (target_mm_s[i] * 1e-3 - velocity_m_s[i]);
            double friction = -DEVICE_DAMPING_N_S_PER_M * velocity_m_s[i];
            velocity_m_s[i] += (pull + friction + force_n[i]) * (h / grip->mass_kg);
            position_m[i] += velocity_m_s[i] * h;
        }
    }
}

/* Sets `grip` unless a value is not finite, the stiffness or damping is negative or the mass is
 * not positive; returns whether it did. */
static int set_grip(Grip *grip, double stiffness_n_per_m, double damping_n_s_per_m,
                    double mass_kg) {
    if (!(isfinite(stiffness_n_per_m) && stiffness_n_per_m >= 0.0 && isfinite(damping_n_s_per_m) &&
          damping_n_s_per_m >= 0.0 && isfinite(mass_kg) && mass_kg > 0.0))
        return 0;
    grip->stiffness_n_per_m = stiffness_n_per_m;
    grip->damping_n_s_per_m = damping_n_s_per_m;
    grip->mass_kg = mass_kg;
    return 1;
}

#endif
