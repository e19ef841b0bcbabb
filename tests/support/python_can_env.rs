//! The Python of the CAN interoperability tests: python-can, cantools and pyserial at
//! pinned versions, from the system or a virtual environment the tests build under
//! `target/tmp/python-can-venv` (`python_env`, which a test includes beside this),
//! failing loudly when neither works.

use crate::python_env;
use std::sync::OnceLock;

const PYTHON_CAN: &str = "python-can==4.6.1";
const CANTOOLS: &str = "cantools==45.1.0";
const PYSERIAL: &str = "pyserial==3.5";

/// The interpreter, set up once per test binary.
pub fn python() -> &'static str {
    static PYTHON: OnceLock<String> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_env::python(
            "python-can-venv",
            &[PYTHON_CAN, CANTOOLS, PYSERIAL],
            "can, cantools, serial",
        )
    })
}
