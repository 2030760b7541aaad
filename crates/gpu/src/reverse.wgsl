// The reverse of one step (compiled after step.wgsl, whose bindings and helpers it uses),
// once the forward's bins, stress and grid are recomputed from the taped state before the
// step: the particle update's reverse, G2P's reverse and the grid update's as a gather by
// node, then P2G's and the stress's reverse as a gather by particle. Every sum in a fixed
// order, as the forward's.

// The state after the step (x, v, C, F per particle).
@group(0) @binding(11) var<storage, read> post: array<f64>;
// dL/d(state), 24 per particle: of the state after the step in, before it out.
@group(0) @binding(12) var<storage, read_write> adj: array<f64>;
// Per particle, 21 numbers: dL/d(gathered velocity) (3), dL/d(gathered C) (9), dL/dFe from
// the particle update (9).
@group(0) @binding(13) var<storage, read_write> radj: array<f64>;
// Per node: dL/d(mass), dL/d(momentum) (3).
@group(0) @binding(14) var<storage, read_write> ggrid: array<f64>;
// Per particle: dL/dM of this step's control matrix (`F^T dL/dFe` for `Fe = F M`).
@group(0) @binding(15) var<storage, read_write> gctrl: array<f64>;

fn adj3(o: u32) -> vec3<f64> { return vec3<f64>(adj[o], adj[o + 1u], adj[o + 2u]); }
fn adj_m(o: u32) -> mat3x3<f64> {
    return mat3x3<f64>(
        vec3<f64>(adj[o], adj[o + 1u], adj[o + 2u]),
        vec3<f64>(adj[o + 3u], adj[o + 4u], adj[o + 5u]),
        vec3<f64>(adj[o + 6u], adj[o + 7u], adj[o + 8u]));
}
fn radj_m(o: u32) -> mat3x3<f64> {
    return mat3x3<f64>(
        vec3<f64>(radj[o], radj[o + 1u], radj[o + 2u]),
        vec3<f64>(radj[o + 3u], radj[o + 4u], radj[o + 5u]),
        vec3<f64>(radj[o + 6u], radj[o + 7u], radj[o + 8u]));
}
fn post_m(o: u32) -> mat3x3<f64> {
    return mat3x3<f64>(
        vec3<f64>(post[o], post[o + 1u], post[o + 2u]),
        vec3<f64>(post[o + 3u], post[o + 4u], post[o + 5u]),
        vec3<f64>(post[o + 6u], post[o + 7u], post[o + 8u]));
}
fn put_adj3(o: u32, v: vec3<f64>) { adj[o] = v.x; adj[o + 1u] = v.y; adj[o + 2u] = v.z; }
fn put_adj_m(o: u32, m: mat3x3<f64>) {
    for (var j = 0u; j < 3u; j++) { put_adj3(o + 3u * j, m[j]); }
}
fn put_radj_m(o: u32, m: mat3x3<f64>) {
    for (var j = 0u; j < 3u; j++) {
        radj[o + 3u * j] = m[j].x; radj[o + 3u * j + 1u] = m[j].y; radj[o + 3u * j + 2u] = m[j].z;
    }
}
fn frob(a: mat3x3<f64>, b: mat3x3<f64>) -> f64 {
    return dot(a[0], b[0]) + dot(a[1], b[1]) + dot(a[2], b[2]);
}

// The differential of fixed-corotated's stress, `dP[dF]`. The rotation's comes from the polar
// decomposition `F = R S`: `R^T dR = Omega`, skew, with `(tr S I - S) omega = axial(R^T dF -
// dF^T R)`.
fn stress_differential(f: mat3x3<f64>, df: mat3x3<f64>) -> mat3x3<f64> {
    let mu = fparams[7];
    let lambda = fparams[8];
    let r = rotation(f);
    let rs = transpose(r) * f;
    let s = 0.5lf * (rs + transpose(rs));
    let w = transpose(r) * df - transpose(df) * r;
    let axial = vec3<f64>(w[1][2], w[2][0], w[0][1]);
    let tr = s[0][0] + s[1][1] + s[2][2];
    let eye = mat3x3<f64>(vec3<f64>(1.0lf, 0.0lf, 0.0lf), vec3<f64>(0.0lf, 1.0lf, 0.0lf), vec3<f64>(0.0lf, 0.0lf, 1.0lf));
    let om = inverse3(tr * eye - s) * axial;
    let omega = mat3x3<f64>(
        vec3<f64>(0.0lf, om.z, -om.y),
        vec3<f64>(-om.z, 0.0lf, om.x),
        vec3<f64>(om.y, -om.x, 0.0lf));
    let dr = r * omega;
    let j = determinant(f);
    let cof = cofactor(f);
    let dj = frob(cof, df);
    let dcof = mat3x3<f64>(
        cross(df[1], f[2]) + cross(f[1], df[2]),
        cross(df[2], f[0]) + cross(f[2], df[0]),
        cross(df[0], f[1]) + cross(f[0], df[1]));
    return 2.0lf * mu * (df - dr) + lambda * (dj * cof + (j - 1.0lf) * dcof);
}

// The particle update's reverse: `x' = x + dt v`, `F' = Fe + dt C Fe`, `v' = v`, `C' = C`.
@compute @workgroup_size(64)
fn rev_advance(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = id.x;
    if (p >= n_particles()) { return; }
    let o = 24u * p;
    let dt = fparams[4];
    let gx = adj3(o);
    let gv = adj3(o + 3u);
    let gc = adj_m(o + 6u);
    let gf = adj_m(o + 15u);
    let fe = work_m(18u * p);
    let cn = post_m(o + 6u);
    let g_vel = gv + dt * gx;
    let g_c = gc + dt * gf * transpose(fe);
    let g_fe = gf + dt * transpose(cn) * gf;
    let r = 21u * p;
    radj[r] = g_vel.x; radj[r + 1u] = g_vel.y; radj[r + 2u] = g_vel.z;
    put_radj_m(r + 3u, g_c);
    put_radj_m(r + 12u, g_fe);
}

// G2P's reverse into each node (`dL/dv_i = sum_p w (g_vel + D^-1 g_C (x_i - x_p))`, a gather
// over the bins that reach it) and the grid update's (`v_i = p_i / m_i`).
@compute @workgroup_size(64)
fn rev_grid(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= node_count()) { return; }
    let node = node_of(i);
    let sup = u32(support());
    let inv_d = fparams[5];
    var gvi = vec3<f64>(0.0lf);
    for (var a = 0u; a < sup; a++) {
        for (var b = 0u; b < sup; b++) {
            for (var c = 0u; c < sup; c++) {
                let o = vec3<u32>(a, b, c);
                let bin = reaching(node, vec3<i32>(o));
                for (var s = bin.x; s < bin.y; s++) {
                    let p = list[s];
                    let pl = place(load3(24u * p));
                    let r = 21u * p;
                    let g_vel = vec3<f64>(radj[r], radj[r + 1u], radj[r + 2u]);
                    gvi += weight_at(pl, o) * (g_vel + inv_d * (radj_m(r + 3u) * offset_at(pl, o)));
                }
            }
        }
    }
    let o = GRID_STRIDE * i;
    let m = grid[o];
    var gm = 0.0lf;
    var gp = vec3<f64>(0.0lf);
    if (m > 0.0lf) {
        // The rules backwards: gravity passes the adjoint on, walls remove the components
        // they removed (each one's mask from the velocity it received, replayed).
        let vq = vec3<f64>(grid[o + 4u], grid[o + 5u], grid[o + 6u]);
        var v = vq;
        for (var r = 0u; r < RULES; r++) {
            gvi = gvi * rule_keeps(r, node, v);
            v = apply_rule(r, node, v);
        }
        gp = gvi / m;
        gm = -dot(gvi, vq) / m;
    }
    ggrid[4u * i] = gm;
    ggrid[4u * i + 1u] = gp.x; ggrid[4u * i + 2u] = gp.y; ggrid[4u * i + 3u] = gp.z;
}

// Per particle, from its stencil's nodes: the weights' and offsets' share of dL/dx (G2P's and
// P2G's), P2G's reverse (dL/dv, dL/dA), the stress's (dL/dC, dL/dFe) and the control's
// (dL/dF, and dL/dM for the host).
@compute @workgroup_size(64)
fn rev_particle(@builtin(global_invocation_id) id: vec3<u32>) {
    let p = id.x;
    if (p >= n_particles()) { return; }
    let o = 24u * p;
    let x = load3(o);
    let pl = place(x);
    let sup = u32(support());
    let dx = fparams[3];
    let inv_d = fparams[5];
    let m = pm[2u * p];
    let q = (fparams[6] * m) * load3(o + 3u);
    let a_mat = work_m(18u * p + 9u);
    let r = 21u * p;
    let g_vel = vec3<f64>(radj[r], radj[r + 1u], radj[r + 2u]);
    let g_c = radj_m(r + 3u);
    let base = vec3<u32>(pl.base);
    var gx = adj3(o);
    var vel = vec3<f64>(0.0lf);
    var gq = vec3<f64>(0.0lf);
    var ga = mat3x3<f64>(vec3<f64>(0.0lf), vec3<f64>(0.0lf), vec3<f64>(0.0lf));
    for (var a = 0u; a < sup; a++) {
        for (var b = 0u; b < sup; b++) {
            for (var c = 0u; c < sup; c++) {
                let wa = vec3<f64>(weight(pl.fx.x, a), weight(pl.fx.y, b), weight(pl.fx.z, c));
                let da = vec3<f64>(dweight(pl.fx.x, a), dweight(pl.fx.y, b), dweight(pl.fx.z, c)) / dx;
                let w = wa.x * wa.y * wa.z;
                let grad_w = vec3<f64>(da.x * wa.y * wa.z, wa.x * da.y * wa.z, wa.x * wa.y * da.z);
                let d = (vec3<f64>(f64(a), f64(b), f64(c)) - pl.fx) * dx;
                let i = node_index(base + vec3<u32>(a, b, c));
                let vi = vec3<f64>(grid[GRID_STRIDE * i + 1u], grid[GRID_STRIDE * i + 2u], grid[GRID_STRIDE * i + 3u]);
                let gm = ggrid[4u * i];
                let gp = vec3<f64>(ggrid[4u * i + 1u], ggrid[4u * i + 2u], ggrid[4u * i + 3u]);
                // G2P: vel = sum w v_i, C = D^-1 sum w v_i d^T.
                gx += grad_w * (dot(vi, g_vel) + inv_d * dot(vi, g_c * d));
                vel += w * vi;
                // P2G: m_i = sum w m, p_i = sum w (q + A d).
                gx += grad_w * (gm * m + dot(gp, q + a_mat * d));
                gq += w * gp;
                ga += mat3x3<f64>(w * d.x * gp, w * d.y * gp, w * d.z * gp);
            }
        }
    }
    // The offsets d = x_i - x_p move against x.
    gx -= inv_d * (transpose(g_c) * vel) + transpose(a_mat) * gq;
    // A = m C + k P(Fe) Fe^T.
    let fe = work_m(18u * p);
    let k = -fparams[4] * pm[2u * p + 1u] * fparams[5];
    let stress = stress_of(fe);
    let g_fe = radj_m(r + 12u) + k * transpose(ga) * stress + stress_differential(fe, k * ga * fe);
    // The control: Fe = F M, F + M, or F.
    let f = load_m(o + 15u);
    var g_f = g_fe;
    let mode = iparams[5];
    if (mode == 1u) {
        g_f = g_fe * transpose(ctrl_m(p));
        let g_m = transpose(f) * g_fe;
        for (var j = 0u; j < 3u; j++) {
            gctrl[9u * p + 3u * j] = g_m[j].x; gctrl[9u * p + 3u * j + 1u] = g_m[j].y; gctrl[9u * p + 3u * j + 2u] = g_m[j].z;
        }
    }
    if (mode == 2u) {
        for (var j = 0u; j < 3u; j++) {
            gctrl[9u * p + 3u * j] = g_fe[j].x; gctrl[9u * p + 3u * j + 1u] = g_fe[j].y; gctrl[9u * p + 3u * j + 2u] = g_fe[j].z;
        }
    }
    put_adj3(o, gx);
    put_adj3(o + 3u, (fparams[6] * m) * gq);
    put_adj_m(o + 6u, m * ga);
    put_adj_m(o + 15u, g_f);
}
