#!/usr/bin/env bash
# Screenshots of the built site (make docs first) with headless Chromium: landing, a guide page,
# an API page, an executed tutorial. Usage: bash screenshots/take.sh
set -euo pipefail
cd "$(dirname "$0")/.."
html=${HTML:-docs/_build/html}
shot() {  # name page height
  chromium --headless=new --no-sandbox --disable-gpu --hide-scrollbars --window-size=1400,"$3" \
    --screenshot="screenshots/$1.png" "file://$(realpath $html)/$2" 2>/dev/null
  echo "screenshots/$1.png <- $2"
}
shot landing index.html 1100
shot guide-adjustment guide/adjustment.html 1400
shot api-camera api/lunarmap.camera.html 1400
shot tutorial-label-to-rpc tutorials/label_to_rpc.html 2600
shot tutorial-lroc-selection tutorials/lroc_selection.html 3600
shot tutorial-example-block tutorials/example_block.html 3000
