//! The adrive ASCII line protocol (placeholder; see the engine commit).
