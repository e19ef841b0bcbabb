//! DBC (placeholder).
