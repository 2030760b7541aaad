#![no_main]
//! libFuzzer target: the OBJ mesh reader must return a mesh or a one-line error.

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Err(e) = morph::geometry::parse_mesh(std::path::Path::new("fuzz.obj"), data) {
        assert!(!e.to_string().contains('\n'));
    }
});
