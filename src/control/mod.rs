//! Control of deformable objects with the ODE form: the rope scene, the gradient controller
//! (Adam over inner batches) and the MPPI baseline, and the `morph rope` comparison.

pub mod rope;
