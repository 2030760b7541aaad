#![no_main]
//! libFuzzer target: settings and scene JSON parse and validate without panicking.

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(s) = serde_json::from_slice::<morph::MorphSettings>(data) {
        let _ = s.validate();
    }
    if let Ok(scene) = serde_json::from_slice::<morph::engine::scene::SceneConfig>(data) {
        let _ = scene.build(vec![1.0; 8]);
    }
});
