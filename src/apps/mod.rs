//! Applications built on the library, as a user's own program would be: the rope controllers
//! (`morph rope`, the second paper), the benchmarks (`morph bench`) and the accuracy study
//! (`morph study`). Nothing below imports them.

pub mod bench;
pub mod rope;
pub mod study;
