//! The scratch buffers of a pass, one kind for both integrators: the grid arrays of a form
//! of `K` fields a node (the Euler step's momentum; the ODE form's momentum and force), in
//! both layouts, with their adjoints for the reverse, and a pool that lends them to
//! concurrent passes. Only the region's nodes hold meaningful values (see [`super::grid`]).

use super::kernel::StencilCache;
use super::transfer::{AxisField, AxisNodes, Node};
use nalgebra::Vector3;

/// The grid buffers one pass reuses.
pub struct GridScratch<const K: usize> {
    /// What P2G scattered: mass and fields, one node each.
    pub nodes: Vec<Node<K>>,
    /// The same by axis (the scatter's own layout).
    pub node_axes: AxisNodes<K>,
    /// The nodal masses.
    pub mass: Vec<f64>,
    /// The grid update's fields (velocity; and acceleration in the ODE form).
    pub fields: [Vec<Vector3<f64>>; K],
    /// The nodes the clamps held, with the control holding each.
    pub held: Vec<(usize, usize)>,
    /// The velocity by axis, for the gather.
    pub velocity_axes: AxisField,
    /// Every particle's stencil, built once a pass.
    pub stencils: StencilCache,
    /// dL/d(fields), one vector a node, and by axis (the reverse gather's scatter).
    pub grad_fields: [Vec<Vector3<f64>>; K],
    pub grad_axes: [AxisField; K],
    /// dL/d(nodes), one node each and by axis.
    pub grad_nodes: Vec<Node<K>>,
    pub grad_node_axes: AxisNodes<K>,
}

impl<const K: usize> Default for GridScratch<K> {
    fn default() -> Self {
        GridScratch {
            nodes: Vec::new(),
            node_axes: AxisNodes::default(),
            mass: Vec::new(),
            fields: std::array::from_fn(|_| Vec::new()),
            held: Vec::new(),
            velocity_axes: AxisField::default(),
            stencils: StencilCache::default(),
            grad_fields: std::array::from_fn(|_| Vec::new()),
            grad_axes: std::array::from_fn(|_| AxisField::default()),
            grad_nodes: Vec::new(),
            grad_node_axes: AxisNodes::default(),
        }
    }
}

/// Scratch lent to concurrent passes (rollouts run in parallel, and a work-stealing thread
/// may start a second pass while one is in flight, so a thread-local buffer would not do).
pub struct Pool<T> {
    free: std::sync::Mutex<Vec<T>>,
}

impl<T> Default for Pool<T> {
    fn default() -> Self {
        Pool {
            free: std::sync::Mutex::new(Vec::new()),
        }
    }
}

impl<T> std::fmt::Debug for Pool<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Pool")
    }
}

impl<T: Default> Pool<T> {
    /// A free buffer, or a new one.
    pub fn take(&self) -> T {
        let found = self.free.lock().map(|mut v| v.pop()).unwrap_or(None);
        found.unwrap_or_default()
    }

    /// Gives `buffer` back for a later pass.
    pub fn put(&self, buffer: T) {
        if let Ok(mut v) = self.free.lock() {
            v.push(buffer);
        }
    }
}
