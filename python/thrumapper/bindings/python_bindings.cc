/*
 * Copyright 2020 Free Software Foundation, Inc.
 *
 * SPDX-License-Identifier: GPL-3.0-or-later
 */

#include <pybind11/pybind11.h>

#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

namespace py = pybind11;

void bind_radar_description(py::module& m);
void bind_manifold(py::module& m);
void bind_jade(py::module& m);
void bind_jade_estimator(py::module& m);
void bind_null_steering(py::module& m);
void bind_projection(py::module& m);
void bind_ofdm_sounding(py::module& m);
void bind_channel_calibration(py::module& m);
void bind_ofdm_sounder(py::module& m);
void bind_ofdm_channel_estimator(py::module& m);
void bind_channel_calibrator(py::module& m);
void bind_slab_echo(py::module& m);

// import_array() returns NULL on newer Pythons, hence the wrapper
void* init_numpy()
{
    import_array();
    return NULL;
}

PYBIND11_MODULE(thrumapper_python, m)
{
    init_numpy();

    // base block classes for the blocks' bindings
    py::module::import("gnuradio.gr");

    bind_radar_description(m);
    bind_manifold(m);
    bind_jade(m);
    bind_jade_estimator(m);
    bind_null_steering(m);
    bind_projection(m);
    bind_ofdm_sounding(m);
    bind_channel_calibration(m);
    bind_ofdm_sounder(m);
    bind_ofdm_channel_estimator(m);
    bind_channel_calibrator(m);
    bind_slab_echo(m);
}
