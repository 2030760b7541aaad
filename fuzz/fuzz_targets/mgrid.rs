#![no_main]
//! libFuzzer target: the `.mgrid` reader and `compare` must not panic; refusals are one line.

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    match morph::io::massgrid::MassGrid::from_bytes(std::path::Path::new("fuzz.mgrid"), data) {
        Ok(g) => {
            let _ = morph::io::massgrid::compare(&g, &g, 1e-5, 1e-8);
        }
        Err(e) => assert!(!e.contains('\n')),
    }
});
