//! A layer's topology (patches, modules, sensors) for Python: read from a
//! layer's channel, or built by a Python driver before it creates its layer.

use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use skinware::{LayerTopology, TopologyBuilder};

use crate::errors;

/// The topology of one layer: its patches, modules and sensors, in frame
/// order (sensor `i` is response `i` of every frame).
#[pyclass(module = "skinware", frozen)]
pub struct Topology {
    pub(crate) inner: LayerTopology,
}

/// A read-only numpy array that Python owns.
pub fn readonly<'py, T: numpy::Element>(py: Python<'py>, values: Vec<T>) -> Bound<'py, PyArray1<T>> {
    let array = PyArray1::from_vec(py, values);
    array.readwrite().make_nonwriteable();
    array
}

#[pymethods]
impl Topology {
    /// A topology from its modules: `modules` is a sequence of
    /// `(patch_id, module_id, uids)`, in frame order; the modules of a patch
    /// are consecutive.
    #[new]
    #[pyo3(signature = (name, modules, sensor_type = "pressure", rate_hz = 0.0))]
    fn new(
        py: Python<'_>,
        name: &str,
        modules: Vec<(u32, u32, Vec<u32>)>,
        sensor_type: &str,
        rate_hz: f64,
    ) -> PyResult<Topology> {
        if !(rate_hz.is_finite() && rate_hz >= 0.0) {
            return Err(errors::invalid(py, format!("layer {name}: rate {rate_hz} Hz must be >= 0 (0 for sporadic)")));
        }
        let mut builder = TopologyBuilder::new(name, sensor_type, rate_hz);
        let mut current_patch = None;
        for (patch_id, module_id, uids) in modules {
            if current_patch != Some(patch_id) {
                builder.patch(patch_id);
                current_patch = Some(patch_id);
            }
            builder.module(module_id, uids);
        }
        let inner = builder.build().map_err(|e| errors::invalid(py, e.to_string()))?;
        Ok(Topology { inner })
    }

    /// `patches` patches of `modules_per_patch` modules of
    /// `sensors_per_module` sensors, numbered from 0 (patch ids, module ids
    /// and sensor uids each count up across the layer).
    #[staticmethod]
    #[pyo3(signature = (name, patches, modules_per_patch, sensors_per_module, sensor_type = "pressure", rate_hz = 0.0))]
    fn uniform(
        py: Python<'_>,
        name: &str,
        patches: u32,
        modules_per_patch: u32,
        sensors_per_module: u32,
        sensor_type: &str,
        rate_hz: f64,
    ) -> PyResult<Topology> {
        let sensors = u64::from(patches) * u64::from(modules_per_patch) * u64::from(sensors_per_module);
        if sensors == 0 || sensors > 1 << 24 {
            return Err(errors::invalid(
                py,
                format!(
                    "layer {name}: {sensors} sensors; give at least one patch, module and sensor, and at most 16 Mi sensors"
                ),
            ));
        }
        let mut modules = Vec::new();
        let mut uid = 0;
        for patch in 0..patches {
            for m in 0..modules_per_patch {
                let uids: Vec<u32> = (uid..uid + sensors_per_module).collect();
                uid += sensors_per_module;
                modules.push((patch, patch * modules_per_patch + m, uids));
            }
        }
        Topology::new(py, name, modules, sensor_type, rate_hz)
    }

    /// The layer's name.
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }

    /// The sensor type, e.g. "pressure".
    #[getter]
    fn sensor_type(&self) -> &str {
        &self.inner.sensor_type
    }

    /// Nominal acquisition rate, Hz (0 for a sporadic layer).
    #[getter]
    fn rate_hz(&self) -> f64 {
        self.inner.rate_hz
    }

    /// Sensors (responses per frame).
    fn __len__(&self) -> usize {
        self.inner.sensors.len()
    }

    /// Each sensor's hardware uid, in frame order.
    #[getter]
    fn uids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        readonly(py, self.inner.sensors.iter().map(|s| s.uid).collect())
    }

    /// Each sensor's module id.
    #[getter]
    fn module_ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        readonly(py, self.inner.sensors.iter().map(|s| self.inner.modules[s.module].id).collect())
    }

    /// Each sensor's patch id.
    #[getter]
    fn patch_ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        let patch_of = |s: &skinware::topology::Sensor| self.inner.patches[self.inner.modules[s.module].patch].id;
        readonly(py, self.inner.sensors.iter().map(patch_of).collect())
    }

    /// The modules, in order: `(module_id, patch_id, first_sensor, end_sensor)`.
    #[getter]
    fn modules(&self) -> Vec<(u32, u32, usize, usize)> {
        let inner = &self.inner;
        inner.modules.iter().map(|m| (m.id, inner.patches[m.patch].id, m.sensors.start, m.sensors.end)).collect()
    }

    /// The patch ids, in order.
    #[getter]
    fn patches(&self) -> Vec<u32> {
        self.inner.patches.iter().map(|p| p.id).collect()
    }

    /// The frame index of the sensor with hardware id `uid`, or `None`.
    fn index_of(&self, uid: u32) -> Option<usize> {
        self.inner.sensor_by_uid(uid)
    }

    fn __eq__(&self, other: &Topology) -> bool {
        self.inner == other.inner
    }

    fn __repr__(&self) -> String {
        let t = &self.inner;
        format!(
            "Topology({:?}, {} sensors of type {:?} in {} modules on {} patches, {} Hz)",
            t.name,
            t.sensors.len(),
            t.sensor_type,
            t.modules.len(),
            t.patches.len(),
            t.rate_hz
        )
    }
}
