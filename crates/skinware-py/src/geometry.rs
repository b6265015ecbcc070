//! A skin's geometry as numpy arrays: computed once by `skin run`, published
//! next to the channels, and read here in one go.

use numpy::ndarray::Array2;
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use skinware_geometry::SkinGeometry;

use crate::errors;
use crate::topology::{Topology, readonly};

/// An (N, K) read-only array.
fn rows<'py, const K: usize>(py: Python<'py>, values: &[[f32; K]]) -> Bound<'py, PyArray2<f32>> {
    let flat: Vec<f32> = values.iter().flatten().copied().collect();
    // The shape matches the vector by construction.
    let array = Array2::from_shape_vec((values.len(), K), flat).unwrap_or_else(|_| Array2::zeros((0, K)));
    let array = PyArray2::from_owned_array(py, array);
    array.readwrite().make_nonwriteable();
    array
}

/// The geometry of a whole skin. Sensors are numbered globally: layer after
/// layer, each in its frame order (`layer_starts` gives where each begins).
/// Every array is read-only and made once.
#[pyclass(module = "skinware", frozen)]
pub struct Geometry {
    inner: SkinGeometry,
    /// Positions, metres, (N, 3) `float32`.
    #[pyo3(get)]
    positions: Py<PyArray2<f32>>,
    /// Outward unit normals, (N, 3) `float32`.
    #[pyo3(get)]
    normals: Py<PyArray2<f32>>,
    /// Each sensor's sensing radius, metres, (N,) `float32`.
    #[pyo3(get)]
    radii: Py<PyArray1<f32>>,
    /// The 2-D map: each sensor's place on the flattened skin, metres, (N, 2) `float32`.
    #[pyo3(get)]
    map: Py<PyArray2<f32>>,
    /// The map's piece of each sensor (the map is cut into pieces where the
    /// surface does not flatten), (N,) `uint32`.
    #[pyo3(get)]
    map_pieces: Py<PyArray1<u32>>,
    /// Each sensor's link index into `links`, (N,) `uint16`.
    #[pyo3(get)]
    link_of: Py<PyArray1<u16>>,
    /// The neighbour graph in CSR form: `(indptr, indices)`, both `uint32`;
    /// the neighbours of sensor i are `indices[indptr[i]:indptr[i+1]]`.
    #[pyo3(get)]
    neighbours: (Py<PyArray1<u32>>, Py<PyArray1<u32>>),
    /// Where each layer's sensors begin, (layers + 1,) `int64`; the last is N.
    #[pyo3(get)]
    layer_starts: Py<PyArray1<i64>>,
    /// Region name to its sensors (global indices, ascending, `uint32`).
    #[pyo3(get)]
    regions: Py<PyDict>,
    /// Sub-regions (disjoint pieces where regions overlap or not): each one's sensors.
    #[pyo3(get)]
    subregions: Vec<Py<PyArray1<u32>>>,
    /// Region name to the indices of its sub-regions in `subregions`.
    #[pyo3(get)]
    region_subregions: Py<PyDict>,
}

#[pymethods]
impl Geometry {
    /// The geometry `skin run` published for `skin`.
    #[staticmethod]
    #[pyo3(signature = (skin = "default"))]
    fn open(py: Python<'_>, skin: &str) -> PyResult<Geometry> {
        let inner = py.detach(|| SkinGeometry::open(skin)).map_err(|e| errors::geometry(py, e))?;
        let neighbours = &inner.neighbours;
        let regions = PyDict::new(py);
        let region_subregions = PyDict::new(py);
        for (r, name) in inner.regions.names.iter().enumerate() {
            regions.set_item(name, readonly(py, inner.regions.sensors[r].clone()))?;
            region_subregions.set_item(name, readonly(py, inner.regions.subregions_of[r].clone()))?;
        }
        let mut starts: Vec<i64> = inner.layer_starts.iter().map(|&s| s as i64).collect();
        if starts.len() == inner.layers.len() {
            starts.push(inner.sensor_count() as i64);
        }
        Ok(Geometry {
            positions: rows(py, &inner.positions).unbind(),
            normals: rows(py, &inner.normals).unbind(),
            radii: readonly(py, inner.radii.clone()).unbind(),
            map: rows(py, &inner.map.positions).unbind(),
            map_pieces: readonly(py, inner.map.piece_of.clone()).unbind(),
            link_of: readonly(py, inner.link_of.clone()).unbind(),
            neighbours: (
                readonly(py, neighbours.offsets.clone()).unbind(),
                readonly(py, neighbours.list.clone()).unbind(),
            ),
            layer_starts: readonly(py, starts).unbind(),
            regions: regions.unbind(),
            subregions: inner.regions.subregion_sensors.iter().map(|s| readonly(py, s.clone()).unbind()).collect(),
            region_subregions: region_subregions.unbind(),
            inner,
        })
    }

    /// The skin's name.
    #[getter]
    fn skin(&self) -> &str {
        &self.inner.skin
    }

    /// Sensors in the whole skin.
    fn __len__(&self) -> usize {
        self.inner.sensor_count()
    }

    /// The robot links the skin covers.
    #[getter]
    fn links(&self) -> Vec<String> {
        self.inner.links.clone()
    }

    /// The layers' names, in global order.
    #[getter]
    fn layers(&self) -> Vec<String> {
        self.inner.layers.iter().map(|l| l.name.clone()).collect()
    }

    /// The topology of layer `layer`.
    fn topology(&self, py: Python<'_>, layer: &str) -> PyResult<Topology> {
        let index = self.layer(py, layer)?;
        Ok(Topology { inner: self.inner.layers[index].clone() })
    }

    /// The global indices of layer `layer`'s sensors, as a `range`.
    fn layer_range(&self, py: Python<'_>, layer: &str) -> PyResult<(usize, usize)> {
        let index = self.layer(py, layer)?;
        let start = self.inner.layer_starts[index];
        Ok((start, start + self.inner.layers[index].sensors.len()))
    }

    /// The global index of sensor `sensor` (its index in frames) of layer `layer`.
    fn global_index(&self, py: Python<'_>, layer: &str, sensor: usize) -> PyResult<usize> {
        let index = self.layer(py, layer)?;
        self.inner.global(index, sensor).ok_or_else(|| {
            errors::invalid(
                py,
                format!(
                    "layer {layer} has {} sensors; sensor {sensor} is not one",
                    self.inner.layers[index].sensors.len()
                ),
            )
        })
    }

    /// Where global sensor `index` sits: `(layer, sensor, uid, module_id, patch_id)`.
    fn locate(&self, py: Python<'_>, index: usize) -> PyResult<(String, usize, u32, u32, u32)> {
        let found = self.inner.locate(index).ok_or_else(|| {
            errors::invalid(py, format!("sensor {index}: the skin has {} sensors", self.inner.sensor_count()))
        })?;
        Ok((self.inner.layers[found.layer].name.clone(), found.sensor, found.uid, found.module_id, found.patch_id))
    }

    /// The sensors of region `name` (global indices).
    fn region<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
        match self.regions.bind(py).get_item(name)? {
            Some(sensors) => Ok(sensors),
            None => Err(errors::invalid(
                py,
                format!(
                    "skin {} has no region {name:?}; its regions are {:?}",
                    self.inner.skin, self.inner.regions.names
                ),
            )),
        }
    }

    fn __repr__(&self) -> String {
        let g = &self.inner;
        format!(
            "<skinware.Geometry {}: {} sensors in {} layers on {} links, {} regions>",
            g.skin,
            g.sensor_count(),
            g.layers.len(),
            g.links.len(),
            g.regions.names.len()
        )
    }
}

impl Geometry {
    fn layer(&self, py: Python<'_>, layer: &str) -> PyResult<usize> {
        self.inner.layer_index(layer).ok_or_else(|| {
            let names: Vec<&str> = self.inner.layers.iter().map(|l| l.name.as_str()).collect();
            errors::invalid(py, format!("skin {} has no layer {layer:?}; its layers are {names:?}", self.inner.skin))
        })
    }
}
