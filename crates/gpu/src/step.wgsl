// The symplectic-Euler MLS-MPM step (APIC, B-spline kernels, fixed-corotated) in f64, as the
// CPU engine's `mpm::pipeline::forward` runs it: bin, stress, P2G, grid update, G2P. Every
// transfer is a gather in a fixed order (no floating-point atomics), so a run gives the same
// bits every time on one device. Particles are binned by their stencil's first node; the bins'
// order is made deterministic by sorting each bin by particle index.

// iparams: particle count, nodes per axis (3), kernel support N, control mode (0 none,
// 1 `Fe = F M`, 2 `Fe = F + M`), node count, the global step.
@group(0) @binding(0) var<storage, read> iparams: array<u32, 8>;
// fparams: origin (3), dx, dt, D^-1, momentum retention, mu, lambda, CFL speed limit; then
// the grid rules in the effect list's order, four numbers each: kind (0 none, 1 gravity,
// 2 sticky walls, 3 slip walls) and its parameters (g; the walls' thickness in cells).
@group(0) @binding(1) var<storage, read> fparams: array<f64, 26>;
// Per particle, 24 numbers: x (3), v (3), C (9, column-major), F (9).
@group(0) @binding(2) var<storage, read_write> state: array<f64>;
// Per particle: mass, rest volume.
@group(0) @binding(3) var<storage, read> pm: array<f64>;
// Per particle: the control matrix M of this step (column-major).
@group(0) @binding(4) var<storage, read> ctrl: array<f64>;
// Per particle, 18 numbers: Fe (9), the affine momentum A = m C + k P Fe^T (9).
@group(0) @binding(5) var<storage, read_write> work: array<f64>;
// Per node: mass, velocity after the grid rules (3), velocity `p / m` before them (3).
@group(0) @binding(6) var<storage, read_write> grid: array<f64>;
// Per node: the bin's count, then (second half) how many are placed.
@group(0) @binding(7) var<storage, read_write> counts: array<atomic<u32>>;
// Per node (and one more): where the bin starts in `list`.
@group(0) @binding(8) var<storage, read_write> starts: array<u32>;
// The particles, bin by bin, each bin in ascending order.
@group(0) @binding(9) var<storage, read_write> list: array<u32>;
// The first step (+1; 0: none yet) in which a particle's stencil left the grid, and the
// first such particle of that step; then the same for a particle not finite or too fast after
// the step. The host sets [1] and [3] to u32's largest value.
@group(0) @binding(10) var<storage, read_write> status: array<atomic<u32>, 4>;

const WG: u32 = 64u;

fn n_particles() -> u32 { return iparams[0]; }
fn step_index() -> u32 { return iparams[7]; }

// Flags particle `p` in this step under kind `k` (0: outside the grid, 1: not finite or too
// fast), unless an earlier step was flagged under it.
fn flag(k: u32, p: u32) {
    let now = step_index() + 1u;
    let seen = atomicCompareExchangeWeak(&status[2u * k], 0u, now);
    if (seen.exchanged || seen.old_value == now) {
        atomicMin(&status[2u * k + 1u], p);
    }
}
fn nodes() -> vec3<u32> { return vec3<u32>(iparams[1], iparams[2], iparams[3]); }
fn support() -> u32 { return iparams[4]; }
fn node_count() -> u32 { return iparams[6]; }
fn node_index(i: vec3<u32>) -> u32 {
    let n = nodes();
    return (i.x * n.y + i.y) * n.z + i.z;
}

fn load3(o: u32) -> vec3<f64> {
    return vec3<f64>(state[o], state[o + 1u], state[o + 2u]);
}
fn store3(o: u32, v: vec3<f64>) {
    state[o] = v.x; state[o + 1u] = v.y; state[o + 2u] = v.z;
}
fn load_m(o: u32) -> mat3x3<f64> {
    return mat3x3<f64>(
        vec3<f64>(state[o], state[o + 1u], state[o + 2u]),
        vec3<f64>(state[o + 3u], state[o + 4u], state[o + 5u]),
        vec3<f64>(state[o + 6u], state[o + 7u], state[o + 8u]));
}
fn store_m(o: u32, m: mat3x3<f64>) {
    for (var j = 0u; j < 3u; j++) {
        state[o + 3u * j] = m[j].x; state[o + 3u * j + 1u] = m[j].y; state[o + 3u * j + 2u] = m[j].z;
    }
}
fn work_m(o: u32) -> mat3x3<f64> {
    return mat3x3<f64>(
        vec3<f64>(work[o], work[o + 1u], work[o + 2u]),
        vec3<f64>(work[o + 3u], work[o + 4u], work[o + 5u]),
        vec3<f64>(work[o + 6u], work[o + 7u], work[o + 8u]));
}
fn store_work_m(o: u32, m: mat3x3<f64>) {
    for (var j = 0u; j < 3u; j++) {
        work[o + 3u * j] = m[j].x; work[o + 3u * j + 1u] = m[j].y; work[o + 3u * j + 2u] = m[j].z;
    }
}
fn ctrl_m(p: u32) -> mat3x3<f64> {
    let o = 9u * p;
    return mat3x3<f64>(
        vec3<f64>(ctrl[o], ctrl[o + 1u], ctrl[o + 2u]),
        vec3<f64>(ctrl[o + 3u], ctrl[o + 4u], ctrl[o + 5u]),
        vec3<f64>(ctrl[o + 6u], ctrl[o + 7u], ctrl[o + 8u]));
}

// The stencil's first node on each axis and the particle's offset `fx` from it, in cells
// (quadratic: fx in [0.5, 1.5); cubic: fx in [1, 2)), as the CPU's `Stencil::new`.
struct Place { base: vec3<i32>, fx: vec3<f64> }

fn place(x: vec3<f64>) -> Place {
    let origin = vec3<f64>(fparams[0], fparams[1], fparams[2]);
    let xg = (x - origin) * (1.0lf / fparams[3]);
    var b: vec3<f64>;
    if (support() == 3u) {
        b = floor(xg - vec3<f64>(0.5lf));
    } else {
        b = floor(xg) - vec3<f64>(1.0lf);
    }
    return Place(vec3<i32>(b), xg - b);
}

// The 1D weight of node `k` of the stencil for offset `fx` (the CPU's `quadratic_pieces`,
// `cubic_pieces`).
fn weight(fx: f64, k: u32) -> f64 {
    if (support() == 3u) {
        let a = 1.5lf - fx;
        let c = fx - 0.5lf;
        let d1 = fx - 1.0lf;
        if (k == 0u) { return 0.5lf * a * a; }
        if (k == 1u) { return 0.75lf - d1 * d1; }
        return 0.5lf * c * c;
    }
    let t = fx - 1.0lf;
    let u = 1.0lf - t;
    if (k == 0u) { return u * u * u / 6.0lf; }
    if (k == 1u) { return (0.5lf * t - 1.0lf) * t * t + 2.0lf / 3.0lf; }
    if (k == 2u) { return (0.5lf * u - 1.0lf) * u * u + 2.0lf / 3.0lf; }
    return t * t * t / 6.0lf;
}

// d(weight)/d(fx) of node `k` (the pieces' derivatives).
fn dweight(fx: f64, k: u32) -> f64 {
    if (support() == 3u) {
        if (k == 0u) { return -(1.5lf - fx); }
        if (k == 1u) { return -2.0lf * (fx - 1.0lf); }
        return fx - 0.5lf;
    }
    let t = fx - 1.0lf;
    let u = 1.0lf - t;
    if (k == 0u) { return -0.5lf * u * u; }
    if (k == 1u) { return (1.5lf * t - 2.0lf) * t; }
    if (k == 2u) { return -(1.5lf * u - 2.0lf) * u; }
    return 0.5lf * t * t;
}

// The node's coordinates.
fn node_of(i: u32) -> vec3<i32> {
    let n = nodes();
    return vec3<i32>(i32(i / (n.y * n.z)), i32((i / n.z) % n.y), i32(i % n.z));
}

// The particles (`list[lo..hi]`) whose stencils reach `node` at offset `o`: the bin of the node
// `o` before it (empty off the grid).
fn reaching(node: vec3<i32>, o: vec3<i32>) -> vec2<u32> {
    let cell = node - o;
    if (any(cell < vec3<i32>(0))) { return vec2<u32>(0u, 0u); }
    let bin = node_index(vec3<u32>(cell));
    return vec2<u32>(starts[bin], starts[bin + 1u]);
}

// A particle's weight at its stencil's node `o`, and the offset `x_i - x_p`.
fn weight_at(pl: Place, o: vec3<u32>) -> f64 {
    return weight(pl.fx.x, o.x) * weight(pl.fx.y, o.y) * weight(pl.fx.z, o.z);
}
fn offset_at(pl: Place, o: vec3<u32>) -> vec3<f64> {
    return (vec3<f64>(o) - pl.fx) * fparams[3];
}

fn in_grid(base: vec3<i32>) -> bool {
    let hi = vec3<i32>(nodes()) - vec3<i32>(i32(support()));
    return all(base >= vec3<i32>(0)) && all(base <= hi);
}

@compute @workgroup_size(64)
fn clear_bins(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i < node_count()) {
        atomicStore(&counts[i], 0u);
        atomicStore(&counts[node_count() + i], 0u);
    }
}

@compute @workgroup_size(64)
fn count_bins(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = id.x;
    if (p >= n_particles()) { return; }
    let pl = place(load3(24u * p));
    if (!in_grid(pl.base)) {
        flag(0u, p);
        return;
    }
    atomicAdd(&counts[node_index(vec3<u32>(pl.base))], 1u);
}

var<workgroup> sums: array<u32, 256>;

// One workgroup of 256: each invocation sums its run of nodes, the runs' sums are scanned in
// workgroup memory, and each invocation writes its run's starts.
@compute @workgroup_size(256)
fn scan_bins(@builtin(local_invocation_id) lid: vec3<u32>) {
    let t = lid.x;
    let total = node_count();
    let run = (total + 255u) / 256u;
    let lo = min(t * run, total);
    let hi = min(lo + run, total);
    var s = 0u;
    for (var i = lo; i < hi; i++) { s += atomicLoad(&counts[i]); }
    sums[t] = s;
    workgroupBarrier();
    for (var step = 1u; step < 256u; step = step * 2u) {
        var add = 0u;
        if (t >= step) { add = sums[t - step]; }
        workgroupBarrier();
        sums[t] += add;
        workgroupBarrier();
    }
    var start = sums[t] - s;
    for (var i = lo; i < hi; i++) {
        starts[i] = start;
        start += atomicLoad(&counts[i]);
    }
    if (t == 255u) { starts[total] = sums[255]; }
}

@compute @workgroup_size(64)
fn place_bins(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = id.x;
    if (p >= n_particles()) { return; }
    let pl = place(load3(24u * p));
    if (!in_grid(pl.base)) { return; }
    let i = node_index(vec3<u32>(pl.base));
    let slot = starts[i] + atomicAdd(&counts[node_count() + i], 1u);
    list[slot] = p;
}

// Each bin in ascending particle order, whatever order the atomics placed them in.
@compute @workgroup_size(64)
fn sort_bins(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= node_count()) { return; }
    let lo = starts[i];
    let hi = starts[i + 1u];
    for (var a = lo + 1u; a < hi; a++) {
        let key = list[a];
        var b = a;
        while (b > lo && list[b - 1u] > key) {
            list[b] = list[b - 1u];
            b -= 1u;
        }
        list[b] = key;
    }
}

fn inverse3(m: mat3x3<f64>) -> mat3x3<f64> {
    let a = m[0]; let b = m[1]; let c = m[2];
    let r0 = cross(b, c); let r1 = cross(c, a); let r2 = cross(a, b);
    let det = dot(a, r0);
    return transpose(mat3x3<f64>(r0, r1, r2)) * (1.0lf / det);
}

// Where Newton's polar iteration stops: the largest change of a column.
const POLAR_TOL: f64 = 1e-15lf;

// The rotation of the polar decomposition `F = R S` (det F > 0), by Newton's iteration
// `R <- (R + R^-T) / 2`, to convergence.
fn rotation(f: mat3x3<f64>) -> mat3x3<f64> {
    var r = f;
    for (var k = 0u; k < 40u; k++) {
        let next = 0.5lf * (r + transpose(inverse3(r)));
        let d = next - r;
        r = next;
        let e = max(max(length(d[0]), length(d[1])), length(d[2]));
        if (e < POLAR_TOL) { break; }
    }
    return r;
}

// The cofactor matrix `J F^-T`, column by column.
fn cofactor(f: mat3x3<f64>) -> mat3x3<f64> {
    return mat3x3<f64>(cross(f[1], f[2]), cross(f[2], f[0]), cross(f[0], f[1]));
}

// Fixed-corotated `P = 2 mu (F - R) + lambda (J - 1) J F^-T`.
fn stress_of(f: mat3x3<f64>) -> mat3x3<f64> {
    let mu = fparams[7];
    let lambda = fparams[8];
    let j = determinant(f);
    return 2.0lf * mu * (f - rotation(f)) + (lambda * (j - 1.0lf)) * cofactor(f);
}

@compute @workgroup_size(64)
fn stress(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = id.x;
    if (p >= n_particles()) { return; }
    let o = 24u * p;
    let f = load_m(o + 15u);
    var fe = f;
    let mode = iparams[5];
    if (mode == 1u) { fe = f * ctrl_m(p); }
    if (mode == 2u) { fe = f + ctrl_m(p); }
    let k = -fparams[4] * pm[2u * p + 1u] * fparams[5];
    let a = pm[2u * p] * load_m(o + 6u) + k * stress_of(fe) * transpose(fe);
    store_work_m(18u * p, fe);
    store_work_m(18u * p + 9u, a);
}

// P2G as a gather and the grid update: node i sums, bin by bin in a fixed order, what the
// particles whose stencils reach it give it (`w (m v + A (x_i - x_p))`, `w m`), then
// `v_i = p_i / m_i`.
@compute @workgroup_size(64)
fn p2g(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= node_count()) { return; }
    let node = node_of(i);
    let sup = u32(support());
    let retention = fparams[6];
    var mass = 0.0lf;
    var mom = vec3<f64>(0.0lf);
    for (var a = 0u; a < sup; a++) {
        for (var b = 0u; b < sup; b++) {
            for (var c = 0u; c < sup; c++) {
                let o = vec3<u32>(a, b, c);
                let bin = reaching(node, vec3<i32>(o));
                for (var s = bin.x; s < bin.y; s++) {
                    let p = list[s];
                    let pl = place(load3(24u * p));
                    let w = weight_at(pl, o);
                    let m = pm[2u * p];
                    let value = (retention * m) * load3(24u * p + 3u);
                    mass += w * m;
                    mom += w * (value + work_m(18u * p + 9u) * offset_at(pl, o));
                }
            }
        }
    }
    var vq = vec3<f64>(0.0lf);
    var v = vec3<f64>(0.0lf);
    if (mass > 0.0lf) {
        vq = mom / mass;
        v = vq;
        for (var r = 0u; r < RULES; r++) {
            v = apply_rule(r, node, v);
        }
    }
    let o = GRID_STRIDE * i;
    grid[o] = mass;
    grid[o + 1u] = v.x; grid[o + 2u] = v.y; grid[o + 3u] = v.z;
    grid[o + 4u] = vq.x; grid[o + 5u] = vq.y; grid[o + 6u] = vq.z;
}

const RULES: u32 = 4u;
const GRID_STRIDE: u32 = 7u;

// Which velocity components rule `r` keeps at `node` for velocity `v` (1: kept).
fn rule_keeps(r: u32, node: vec3<i32>, v: vec3<f64>) -> vec3<f64> {
    let kind = u32(fparams[10u + 4u * r]);
    if (kind < 2u) { return vec3<f64>(1.0lf); }
    let t = i32(fparams[11u + 4u * r]);
    let n = vec3<i32>(nodes());
    let low = node < vec3<i32>(t);
    let high = node + vec3<i32>(t) >= n;
    if (!any(low) && !any(high)) { return vec3<f64>(1.0lf); }
    if (kind == 2u) { return vec3<f64>(0.0lf); }
    // Slip: the component into a wall (v . outward normal > 0) goes.
    var keep = vec3<f64>(1.0lf);
    for (var a = 0; a < 3; a++) {
        if ((low[a] && v[a] < 0.0lf) || (high[a] && !low[a] && v[a] > 0.0lf)) { keep[a] = 0.0lf; }
    }
    return keep;
}

// Rule `r` applied to a node's velocity (the CPU's effects' `apply_grid` in the Euler step).
fn apply_rule(r: u32, node: vec3<i32>, v: vec3<f64>) -> vec3<f64> {
    let kind = u32(fparams[10u + 4u * r]);
    if (kind == 1u) {
        let g = vec3<f64>(fparams[11u + 4u * r], fparams[12u + 4u * r], fparams[13u + 4u * r]);
        return v + fparams[4] * g;
    }
    let keep = rule_keeps(r, node, v);
    return select(vec3<f64>(0.0lf), v, keep > vec3<f64>(0.5lf));
}

fn is_finite(x: f64) -> bool {
    return x == x && abs(x) <= 1.7976931348623157e308lf;
}

// G2P and the particle update: `v_p = sum w v_i`, `C_p = D^-1 sum w v_i (x_i - x_p)^T`,
// `x += dt v_p`, `F = Fe + dt C Fe`.
@compute @workgroup_size(64)
fn g2p(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = id.x;
    if (p >= n_particles()) { return; }
    let o = 24u * p;
    let x = load3(o);
    let pl = place(x);
    let sup = u32(support());
    let base = vec3<u32>(pl.base);
    var vel = vec3<f64>(0.0lf);
    var b_mat = mat3x3<f64>(vec3<f64>(0.0lf), vec3<f64>(0.0lf), vec3<f64>(0.0lf));
    for (var a = 0u; a < sup; a++) {
        for (var b = 0u; b < sup; b++) {
            for (var c = 0u; c < sup; c++) {
                let k = vec3<u32>(a, b, c);
                let w = weight_at(pl, k);
                let d = offset_at(pl, k);
                let i = node_index(base + k);
                let vi = vec3<f64>(grid[GRID_STRIDE * i + 1u], grid[GRID_STRIDE * i + 2u], grid[GRID_STRIDE * i + 3u]);
                vel += w * vi;
                b_mat += mat3x3<f64>(w * d.x * vi, w * d.y * vi, w * d.z * vi);
            }
        }
    }
    let cn = fparams[5] * b_mat;
    let dt = fparams[4];
    let fe = work_m(18u * p);
    let xn = x + dt * vel;
    store3(o, xn);
    store3(o + 3u, vel);
    store_m(o + 6u, cn);
    store_m(o + 15u, fe + dt * cn * fe);
    var ok = length(vel) <= fparams[9];
    for (var k = 0u; k < 24u; k++) { ok = ok && is_finite(state[o + k]); }
    if (!ok) { flag(1u, p); }
}
