# The README's `py scripts/serve.py` for those who type .\scripts\serve.ps1 (scripts/serve.py says how; quoting: docs/windows.md).
$python = if (Get-Command py -ErrorAction SilentlyContinue) { 'py' } else { 'python' }; & $python (Join-Path $PSScriptRoot 'serve.py') @args; exit $LASTEXITCODE
