//! The painted stacks (boards/stack.rs): the main one and, by address, the background
//! executor's.

include!("../../stack.rs");
