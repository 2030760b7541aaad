//! The field's particle surfacer, splashsurf (its reconstruction pipeline, as its command line
//! runs it), as one of the rebuilt surface's methods: for comparison with the deformed kernel
//! (docs/geometry.md, "Measured: deformed kernels against splashsurf"), and for users who want
//! a fluid-style surface. It sees positions only: a particle's deformation is unknown to it.
//!
//! Settings, in units of the particle radius `r` (the sphere of the particle's rest volume,
//! `r = (3/(4 pi))^(1/3)` rest spacings): splashsurf's README's recommended ones, a smoothing
//! length of 2 `r`, cubes of 0.5 `r`, iso threshold 0.6, marching-cubes cleanup, barnacle
//! decimation, and 25 steps of Laplacian smoothing weighted by the particles' neighbour count.
//!
//! It runs on one thread of a pool of its own: splashsurf sorts particles into subdomains
//! through thread-local lists merged in whatever order the threads finish, so on several
//! threads the same particles can give a mesh with its vertices in another order (a CI run
//! caught frame 2 differing between 1 thread and 2). Our outputs are bitwise reproducible
//! whatever the thread count; one thread keeps splashsurf so.

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
    params.enable_multi_threading = false;
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
    let result = one_thread()?
        .install(|| reconstruction_pipeline::<i64, f64>(&particles, &[], &params, &post))
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

/// The one-thread pool splashsurf runs in (its parallel paths are not reproducible), built once.
fn one_thread() -> Result<&'static rayon::ThreadPool, SurfaceError> {
    static POOL: std::sync::OnceLock<Result<rayon::ThreadPool, String>> =
        std::sync::OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .thread_name(|_| "splashsurf".into())
            .build()
            .map_err(|e| e.to_string())
    })
    .as_ref()
    .map_err(|e| SurfaceError::External(format!("splashsurf's thread: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A jittered ball of particles, enough for splashsurf to cut it into many subdomains.
    fn jittered_ball(n: i32) -> Vec<Vector3<f64>> {
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut jitter = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.3
        };
        let mut out = Vec::new();
        for i in -n..=n {
            for j in -n..=n {
                for k in -n..=n {
                    if i * i + j * j + k * k <= n * n {
                        let p = Vector3::new(i as f64, j as f64, k as f64);
                        out.push(p + Vector3::new(jitter(), jitter(), jitter()));
                    }
                }
            }
        }
        out
    }

    #[test]
    fn the_same_particles_give_the_same_mesh_whatever_pool_it_is_called_from() {
        let particles = jittered_ball(22);
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| extract_splashsurf_surface(&particles, 1.0).unwrap())
        };
        let one = on(1);
        assert!(one.topology().is_closed());
        for _ in 0..3 {
            let many = on(8);
            assert!(
                many.vertices == one.vertices && many.triangles == one.triangles,
                "splashsurf's mesh differs when called from an 8-thread pool"
            );
        }
    }
}
