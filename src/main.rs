fn main() {
    #[allow(unsafe_code)]
    // One malloc arena for every thread: adrive's threads allocate little and never on
    // the command path, and each extra arena costs resident memory of its own.
    // SAFETY: mallopt only sets an allocator parameter, before any thread starts.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1)
    };
    std::process::exit(adrive::cli::main());
}
