//! Job parameters as JSON (the `params` field of `POST /v1/jobs`, as the service reads it) and
//! an edit's reference parameters: never a panic, and whatever parses and validates survives a
//! round trip.
#![no_main]

use covec::Params;
use covec::edit::ReferenceParams;
use covec::service::InputLimits;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // The service parses the field to a JSON value first, then to parameters.
    if let Ok(value) = serde_json::from_slice::<serde_json::Value>(data)
        && let Ok(params) = serde_json::from_value::<Params>(value)
        && params.validate(&InputLimits::default().params()).is_ok()
    {
        let json = serde_json::to_vec(&params).expect("params serialise");
        let again: Params = serde_json::from_slice(&json).expect("params parse back");
        assert_eq!(again, params);
    }
    let _ = serde_json::from_slice::<ReferenceParams>(data);
});
