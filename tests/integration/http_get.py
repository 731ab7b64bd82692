#!/usr/bin/env python3
"""GET a URL, print the HTTP status code and optionally save the body.

    http_get.py URL [OUT_FILE]

Prints 000 when nothing answers (as curl does); exits 0 either way, so
the caller judges the code.
"""
import sys
import urllib.error
import urllib.request

url = sys.argv[1]
out = sys.argv[2] if len(sys.argv) > 2 else None
# Straight to the address: the tests serve on loopback, never via a proxy.
opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
try:
    with opener.open(url, timeout=10) as response:
        code, body = response.status, response.read()
except urllib.error.HTTPError as e:
    code, body = e.code, e.read()
except (urllib.error.URLError, OSError):
    code, body = 0, b""
if out:
    with open(out, "wb") as f:
        f.write(body)
print(f"{code:03d}")
