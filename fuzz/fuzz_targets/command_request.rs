//! A subscriber's command line with its rights (`parse_request`, issue 12):
//! any bytes give a request or an error, never a panic; a request is only
//! ever made from a JSON object (no key given twice), and its token, when
//! there is one, is the object's "token" string.
#![no_main]

use fieldcal::daemon::publish::{CommandError, parse_request};
use libfuzzer_sys::fuzz_target;
use serde_json::Value;

fuzz_target!(|data: &[u8]| {
    match parse_request(data) {
        Ok(request) => {
            let value: Value = serde_json::from_slice(data).expect("a request is JSON");
            let object = value.as_object().expect("a request is an object");
            assert_eq!(
                object.get("token").and_then(Value::as_str).is_some(),
                request.token.is_some()
            );
        }
        Err(CommandError::DuplicateKey(key)) => {
            // serde_json keeps the last of a repeated key: the key is there.
            let value: Value = serde_json::from_slice(data).expect("duplicates are JSON");
            assert!(value.as_object().is_some_and(|o| o.contains_key(&key)));
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
});
