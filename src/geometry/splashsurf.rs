//! The field's particle surfacer, splashsurf (its reconstruction pipeline, as its command line
//! runs it), as one of the rebuilt surface's methods: for comparison with the deformed kernel
//! (docs/geometry.md, "Measured: deformed kernels against splashsurf"), and for users who want
//! a fluid-style surface. It sees positions only: a particle's deformation is unknown to it.
//!
//! Settings, in units of the particle radius `r` (the sphere of the particle's rest volume,
//! `r = (3/(4 pi))^(1/3)` rest spacings): splashsurf's README's recommended ones, a smoothing
//! length of 2 `r`, cubes of 0.5 `r`, iso threshold 0.6, marching-cubes cleanup, barnacle
//! decimation, and 25 steps of Laplacian smoothing weighted by the particles' neighbour count.

use super::mesh::TriMesh;
use super::surface::SurfaceError;
use nalgebra::Vector3;
use splashsurf::reconstruct::{ReconstructionPostprocessingParameters, reconstruction_pipeline};
use splashsurf_lib::nalgebra::Vector3 as SsVector3;

/// splashsurf's smoothing length, in particle radii.
const SMOOTHING_LENGTH: f64 = 2.0;
/// Marching-cubes cell edge, in particle radii.
const CUBE_SIZE: f64 = 0.5;
/// Iso level, as a share of the rest density.
const ISO_THRESHOLD: f64 = 0.6;
/// Weighted Laplacian smoothing steps.
const SMOOTHING_STEPS: usize = 25;
/// splashsurf's neighbour-count normalization for its smoothing weights (its default).
const WEIGHT_NORMALIZATION: f64 = 13.0;

/// A closed surface around `positions` (particles `spacing` apart at rest) by splashsurf.
pub fn extract_splashsurf_surface(
    positions: &[Vector3<f64>],
    spacing: f64,
) -> Result<TriMesh, SurfaceError> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(SurfaceError::BadSpacing(spacing));
    }
    if let Some(p) = positions
        .iter()
        .position(|x| !x.iter().all(|c| c.is_finite()))
    {
        return Err(SurfaceError::NonFinite(p));
    }
    if positions.is_empty() {
        return Ok(TriMesh::default());
    }
    let radius = spacing * (3.0 / (4.0 * std::f64::consts::PI)).cbrt();
    let mut params = splashsurf_lib::Parameters::new(
        radius,
        2.0 * SMOOTHING_LENGTH * radius,
        CUBE_SIZE * radius,
    );
    params.iso_surface_threshold = ISO_THRESHOLD;
    let mut post = ReconstructionPostprocessingParameters::new();
    post.mesh_cleanup = true;
    post.decimate_barnacles = true;
    post.mesh_smoothing_iters = Some(SMOOTHING_STEPS);
    post.mesh_smoothing_weights = true;
    post.mesh_smoothing_weights_normalization = WEIGHT_NORMALIZATION;
    let particles: Vec<SsVector3<f64>> = positions
        .iter()
        .map(|p| SsVector3::new(p.x, p.y, p.z))
        .collect();
    let result = reconstruction_pipeline::<i64, f64>(&particles, &[], &params, &post)
        .map_err(|e| SurfaceError::External(format!("{e:#}")))?;
    let mesh = result
        .tri_mesh
        .ok_or_else(|| SurfaceError::External("splashsurf returned no triangle mesh".into()))?
        .mesh;
    Ok(TriMesh {
        vertices: mesh
            .vertices
            .iter()
            .map(|v| Vector3::new(v.x, v.y, v.z))
            .collect(),
        triangles: mesh.triangles.iter().map(|t| t.map(|i| i as u32)).collect(),
    })
}
