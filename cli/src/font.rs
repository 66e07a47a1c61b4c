//! The font for every picture the CLI draws (plots, heat maps, overlays): DejaVu
//! Sans, shipped inside the binary (cli/assets/, license beside it), so a minimal
//! base station without fonts draws text too.

use plotters::style::{FontStyle, register_font};

/// DejaVu Sans (Bitstream Vera license, cli/assets/DejaVuSans.LICENSE).
static DEJAVU_SANS: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// Registers the embedded font as plotters' `sans-serif`, once.
pub fn load() -> anyhow::Result<()> {
    static LOADED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    LOADED
        .get_or_init(|| {
            register_font("sans-serif", FontStyle::Normal, DEJAVU_SANS)
                .map_err(|_| "the embedded font does not load".to_string())
        })
        .clone()
        .map_err(anyhow::Error::msg)
}
