fn main() {
    std::process::exit(adrive::cli::main());
}
