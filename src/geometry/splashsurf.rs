//! The field's particle surfacer, splashsurf (its library: reconstruction, then the
//! post-processing its command line runs with these settings), as one of the rebuilt surface's
//! methods: for comparison with the deformed kernel (docs/lab/2026-12-08-surfaces-record.md, "Measured: deformed
//! kernels against splashsurf"), and for users who want a fluid-style surface. It sees
//! positions only: a particle's deformation is unknown to it.
//!
//! Settings, in units of the particle radius `r` (the sphere of the particle's rest volume,
//! `r = (3/(4 pi))^(1/3)` rest spacings): splashsurf's README's recommended ones, a smoothing
//! length of 2 `r`, cubes of 0.5 `r`, iso threshold 0.6, marching-cubes cleanup, barnacle
//! decimation, and 25 steps of Laplacian smoothing weighted by the particles' neighbour count.
//! The steps are the library's own functions in the order `splashsurf reconstruct` calls them
//! (its command-line crate would add a 30 s compile of file formats we do not use).
//!
//! It runs on one thread of a pool of its own: splashsurf sorts particles into subdomains
//! through thread-local lists merged in whatever order the threads finish, so on several
//! threads the same particles can give a mesh with its vertices in another order (a CI run
//! caught frame 2 differing between 1 thread and 2). Our outputs are bitwise reproducible
//! whatever the thread count; one thread keeps splashsurf so.

use super::mesh::TriMesh;
use super::surface::SurfaceError;
use nalgebra::Vector3;
use splashsurf_lib::nalgebra::Vector3 as SsVector3;
use splashsurf_lib::postprocessing::{
    decimation, marching_cubes_cleanup, par_laplacian_smoothing_inplace,
};
use splashsurf_lib::sph_interpolation::SphInterpolator;

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
/// Rounds of marching-cubes cleanup (splashsurf's command line runs 5).
const CLEANUP_ROUNDS: usize = 5;

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
    // The smoothing weights count each particle's neighbours.
    params.global_neighborhood_list = true;
    let particles: Vec<SsVector3<f64>> = positions
        .iter()
        .map(|p| SsVector3::new(p.x, p.y, p.z))
        .collect();
    let mesh = one_thread()?.install(|| reconstruct_and_smooth(&particles, &params))?;
    Ok(TriMesh {
        vertices: mesh
            .vertices
            .iter()
            .map(|v| Vector3::new(v.x, v.y, v.z))
            .collect(),
        triangles: mesh.triangles.iter().map(|t| t.map(|i| i as u32)).collect(),
    })
}

/// splashsurf's reconstruction, cleanup, barnacle decimation and neighbour-weighted smoothing.
fn reconstruct_and_smooth(
    particles: &[SsVector3<f64>],
    params: &splashsurf_lib::Parameters<f64>,
) -> Result<splashsurf_lib::mesh::TriMesh3d<f64>, SurfaceError> {
    let external = |what: &str| SurfaceError::External(format!("splashsurf returned no {what}"));
    let mut reconstruction = splashsurf_lib::reconstruct_surface::<i64, f64>(particles, params)
        .map_err(|e| SurfaceError::External(format!("{e:#}")))?;
    let mut mesh = std::mem::take(&mut reconstruction.mesh);
    marching_cubes_cleanup(&mut mesh, &reconstruction.grid, None, CLEANUP_ROUNDS, false);
    let connectivity = decimation(&mut mesh, false);
    let densities = reconstruction
        .particle_densities
        .as_ref()
        .ok_or_else(|| external("densities"))?;
    let neighbours = reconstruction
        .particle_neighbors
        .as_ref()
        .ok_or_else(|| external("neighbour lists"))?;
    let h = params.compact_support_radius;
    let rest_volume = 4.0 * std::f64::consts::FRAC_PI_3 * params.particle_radius.powi(3);
    let rest_mass = rest_volume * params.rest_density;
    let interpolator = SphInterpolator::new(particles, densities, rest_mass, h);
    // Each particle's neighbour count, weighted down with distance, at the vertices.
    let counts: Vec<f64> = neighbours
        .iter()
        .enumerate()
        .map(|(i, near)| {
            near.iter()
                .map(|&j| {
                    1.0 - ((particles[i] - particles[j]).norm_squared() / (h * h)).clamp(0.0, 1.0)
                })
                .fold(0.0, |sum, w| sum + w)
        })
        .collect();
    let at_vertices = interpolator.interpolate_scalar_quantity(&counts, &mesh.vertices, true);
    // Full smoothing where the body is dense, none at its sparse edges (a smooth step).
    let weights: Vec<f64> = at_vertices
        .iter()
        .map(|&n| (n.max(0.0) / WEIGHT_NORMALIZATION).min(1.0))
        .map(|x| x.powi(5) * 6.0 - x.powi(4) * 15.0 + x.powi(3) * 10.0)
        .collect();
    par_laplacian_smoothing_inplace(&mut mesh, &connectivity, SMOOTHING_STEPS, 1.0, &weights);
    Ok(mesh)
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
