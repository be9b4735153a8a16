<#
.SYNOPSIS
Set up the simulator from the project's own files and start it: the PowerShell twin of
scripts/serve.sh, for Windows.

.DESCRIPTION
Usage: .\scripts\serve.ps1 [tmcl-server arguments]

Default: TCP 127.0.0.1:2323.  Windows has no pseudo-terminals: for the TMCL-IDE, serve one end
of a com0com pair and open the other end in the IDE:

    .\scripts\serve.ps1 --serial COM11

(docs\windows.md, step by step).  The first start creates .venv and installs tmcl-sim with what
the README's examples use; later starts reuse it and start at once (a stamp in .venv records
what the setup used).  $env:PYTHON picks the Python; otherwise the first of
"py -3.13", "py -3.12", "py -3.11", python3.13, python3.12, python3.11, python, python3 that is
3.11 or newer.

If PowerShell refuses to run scripts: powershell -ExecutionPolicy Bypass -File scripts\serve.ps1
#>

$ErrorActionPreference = 'Stop'
Set-Location (Split-Path -Parent $PSScriptRoot)

# examples: pytrinamic; fast: uvloop (not on Windows: its marker skips it); plot: matplotlib;
# http: aiohttp (the dashboard); tools: pytrinamic for tmcl --connection
$Extras = 'examples,fast,plot,http,tools'
$VenvPython = Join-Path '.venv' 'Scripts\python.exe'
$Stamp = Join-Path '.venv' ('.setup-' + ($Extras -replace ',', '-'))

function Say([string]$Text) { [Console]::Error.WriteLine("serve.ps1: $Text") }

# A command line (program and arguments) for a Python >= 3.11 with venv, or $null.
function Find-Python {
    $check = 'import sys, venv; sys.exit(sys.version_info < (3, 11))'
    if ($env:PYTHON) {
        $candidates = @(, @($env:PYTHON))
    } else {
        $candidates = @(@('py', '-3.13'), @('py', '-3.12'), @('py', '-3.11'), @('python3.13'),
                        @('python3.12'), @('python3.11'), @('python'), @('python3'))
    }
    foreach ($candidate in $candidates) {
        if (-not (Get-Command $candidate[0] -ErrorAction SilentlyContinue)) { continue }
        $rest = @($candidate | Select-Object -Skip 1)
        & $candidate[0] @rest -c $check 2>$null
        if ($LASTEXITCODE -eq 0) { return , $candidate }
    }
    return $null
}

# What the setup depends on, as one hash: pyproject.toml, setup.py, the extras, $env:PYTHON.
function Get-SetupKey {
    $text = (Get-Content -Raw pyproject.toml) + (Get-Content -Raw setup.py) + "`n$Extras`n$env:PYTHON"
    $sha = [System.Security.Cryptography.SHA256]::Create()
    $bytes = $sha.ComputeHash([System.Text.Encoding]::UTF8.GetBytes($text))
    return ([System.BitConverter]::ToString($bytes) -replace '-', '')
}

$Key = Get-SetupKey
$UpToDate = (Test-Path $VenvPython) -and (Test-Path $Stamp) -and
            ((Get-Content $Stamp -TotalCount 1) -eq $Key)
if ($UpToDate) {
    Say ((Get-Content $Stamp)[1] + ' (.venv is up to date)')
} else {
    $Python = Find-Python
    if (-not $Python) {
        if ($env:PYTHON) { Say "error: PYTHON=$env:PYTHON is not a Python >= 3.11 with venv" }
        else { Say 'error: no Python >= 3.11 found (tried py -3.13/-3.12/-3.11, python3.1x, python, python3); install one from python.org or set $env:PYTHON' }
        exit 1
    }
    $Program = $Python[0]
    $Rest = @($Python | Select-Object -Skip 1)
    $Version = (& $Program @Rest -c 'import sys; print("%d.%d.%d" % sys.version_info[:3])').Trim()
    $Name = ($Python -join ' ')
    Say "using $Name (Python $Version, $((Get-Command $Program).Source))"
    $Existing = $null
    if (Test-Path $VenvPython) {
        $Existing = (& $VenvPython -c 'import sys; print("%d.%d.%d" % sys.version_info[:3])' 2>$null)
    }
    if ($Existing -and $Existing.Trim() -eq $Version) {
        Say 'setting up .venv again: pyproject.toml, the extras or PYTHON changed'
    } else {
        Say "creating .venv with $Name ..."
        & $Program @Rest -m venv --clear .venv
        if ($LASTEXITCODE -ne 0) { Say 'error: creating .venv failed'; exit 1 }
        Remove-Item -Force -ErrorAction SilentlyContinue (Join-Path '.venv' '.setup-*')
    }
    Say "installing tmcl-sim with the extras $Extras into .venv (a minute or two the first time) ..."
    & $VenvPython -m pip install --progress-bar off -e ".[$Extras]"
    if ($LASTEXITCODE -ne 0) { Say 'error: pip install failed (see above)'; exit 1 }
    Set-Content -Path $Stamp -Value @($Key, "using .venv (Python $Version, set up with $Name)")
    Say '.venv is ready'
}

if (-not ($args -match '^--serial(=|$)')) {
    Say 'for the TMCL-IDE: .\scripts\serve.ps1 --serial COM11 (one end of a com0com pair; docs\windows.md)'
}
& (Join-Path '.venv' 'Scripts\tmcl-server.exe') @args
exit $LASTEXITCODE
