# The README's `py scripts/test.py` for those who type .\scripts\test.ps1 (scripts/test.py says how; quoting: docs/windows.md).
$python = if (Get-Command py -ErrorAction SilentlyContinue) { 'py' } else { 'python' }; & $python (Join-Path $PSScriptRoot 'test.py') @args; exit $LASTEXITCODE
